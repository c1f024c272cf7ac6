"""User docs speak to users: no tracker issue numbers or commit hashes, which a reader of the
docs cannot see (history belongs in the commit log)."""
from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
USER_DOCS = ["README.md", "envs/README.md", "scenarios/README.md", "examples/README.md", "docs/*.md", "docs/*/*.md"]
ISSUE = re.compile(r"\b[Ii]ssues? #?\d+\b|\(#\d+\)")
HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")  # hex with a letter and a digit


def _hits(text: str) -> list[str]:
    return [m.group(0) for pattern in (ISSUE, HASH) for m in pattern.finditer(text)]


def test_the_patterns_find_issue_numbers_and_hashes():
    assert _hits("fixed in issue 13 (commit 0a83395), see #12 (#4)") == ["issue 13", "(#4)", "0a83395"]
    assert _hits("signal type `1000001`, 2026-11-23, sha256, deadbeef, feat2map 0.1.0") == []


def test_user_docs_name_no_issue_numbers_or_commit_hashes():
    found = []
    for pattern in USER_DOCS:
        for path in sorted(REPO.glob(pattern)):
            for i, line in enumerate(path.read_text().splitlines(), 1):
                found += [f"{path.relative_to(REPO)}:{i}: {hit}" for hit in _hits(line)]
    assert found == []


def test_shell_blocks_paste_as_written():
    """A command line in a ```bash block runs when pasted: no `[--option]` usage brackets."""
    found = []
    for pattern in USER_DOCS:
        for path in sorted(REPO.glob(pattern)):
            block = False
            for i, line in enumerate(path.read_text().splitlines(), 1):
                if line.startswith("```"):
                    block = line.strip() in ("```bash", "```sh")
                elif block and re.search(r"\[--?\w", line.split("  #", 1)[0]):
                    found.append(f"{path.relative_to(REPO)}:{i}: {line.strip()}")
    assert found == []
