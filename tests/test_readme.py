"""The README's command-line block runs as written, copy-pasted after the demo: in a fresh
directory holding the demo's map outputs (made by the demo's own commands, parsed from
scripts/demo.sh, run twice: the demo runs again over its own outputs) and the examples, every
line succeeds, and nothing is written outside out/.
Lines that read ../shared/maps run when those maps are present (beside the repository)."""
from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO, SHARED_MAPS

pytestmark = pytest.mark.slow


def readme_block() -> list[str]:
    """The lines of the bash block under the README's "## Command line" heading."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("\n## Command line\n", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)\n```", section, re.S)
    assert block, "README.md: no bash block under '## Command line'"
    return block.group(1).splitlines()


def demo_map_commands() -> list[str]:
    """The demo's feat2map commands that make out/demo/m1 (not its rollout), with its variables filled in."""
    script = (REPO / "scripts" / "demo.sh").read_text(encoding="utf-8")
    values = dict(re.findall(r"^(\w+)=(\S+)", script, re.M))
    lines = [ln.split("  #")[0].strip() for ln in script.splitlines() if ln.startswith("$f2m ")]
    lines = [ln for ln in lines if not ln.startswith("$f2m rollout")]
    assert lines, "scripts/demo.sh: no $f2m commands"
    return [re.sub(r"\$(\w+)", lambda m: values[m.group(1)], ln) + " --quiet" * ln.startswith("$f2m generate")
            for ln in lines]


def files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and ".venv" not in p.parts}


def test_readme_command_block_runs_as_written(tmp_path):
    venv = Path(sys.prefix)
    if not (venv / "bin" / "activate").is_file():
        pytest.skip(f"the tests do not run from a virtual environment ({venv}); the README block activates .venv: "
                    "bash scripts/setup.sh dev, then .venv/bin/python -m pytest")
    lines = readme_block()
    commands = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    assert commands[0].startswith("source .venv/bin/activate")
    assert all(c.startswith(("feat2map ", "source ")) for c in commands), commands
    shared = SHARED_MAPS.is_dir()
    run_lines = [c for c in commands if shared or "../shared" not in c]

    repo = tmp_path / "repo"
    repo.mkdir()
    shutil.copytree(REPO / "examples", repo / "examples")
    shutil.copytree(REPO / "adapters", repo / "adapters")  # examples/bridge_planner.py imports adapters/bridge_client.py
    (repo / ".venv").symlink_to(venv)
    if shared:
        (tmp_path / "shared").symlink_to(SHARED_MAPS.parent)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "SOURCE_DATE_EPOCH")}
    env.update(SDL_VIDEODRIVER="offscreen", MPLBACKEND="Agg")
    demo = [c.replace("$f2m", str(venv / "bin" / "feat2map")) for c in demo_map_commands()]
    for again in (False, True):  # the demo runs again over its own outputs (its folders hold only what it wrote)
        r = subprocess.run(["bash", "-euo", "pipefail", "-c", "\n".join(demo)], cwd=repo, env=env,
                           capture_output=True, text=True)
        assert r.returncode == 0, (again, r.stderr[-2000:])
    before = files(repo)

    script = "\n".join(["set -euo pipefail", *(f"echo {shlex.quote('>>> ' + c)} >&2\n{c}" for c in run_lines)])
    r = subprocess.run(["bash", "-c", script], cwd=repo, env=env, capture_output=True, text=True)
    ran = re.findall(r"^>>> (.*)$", r.stderr, re.M)
    assert r.returncode == 0, f"README line failed: {ran[-1] if ran else '?'}\n{r.stderr[-3000:]}"
    assert len(ran) == len(run_lines)

    outside = sorted(f for f in files(repo) - before if not f.startswith("out/"))
    assert not outside, f"the README's commands wrote outside out/: {outside}"
    written = files(repo) - before
    for line in run_lines:  # every output a line names exists
        for path in re.findall(r"--(?:out|picture) (\S+)", line):
            assert any(f == path or f.startswith(path.rstrip("/") + "/") for f in written), (line, path)
    assert "usage: feat2map" in r.stdout and "J0" in r.stdout
    summary = json.loads((repo / "out" / "r3" / "summary.json").read_text())  # the bridge line, --fail-on none
    failed = [o["name"] for o in summary["outcomes"] if o["outcome"] != "completed"]
    assert all(o["outcome"] != "error" for o in summary["outcomes"]), summary["outcomes"]  # the planner drove
    assert not failed and not summary["gifs"], \
        [(o["name"], o["outcome"], o["message"][:300]) for o in summary["outcomes"]]  # as the README says: all three
