"""Rewrite the config and info tables of envs/README.md from `envs/config.py` SETTINGS and
`envs/info.py` INFO_KEYS (tests/envs/test_config.py fails while they differ).

    .venv/bin/python scripts/env_tables.py          # rewrite envs/README.md
    .venv/bin/python scripts/env_tables.py --check  # exit 1 if it is stale
"""
from __future__ import annotations

import sys
from pathlib import Path

from feat2map.atomic import write_text
from feat2map.envs import config, info

README = Path(__file__).resolve().parents[1] / "envs" / "README.md"


def with_tables(text: str) -> str:
    """`text` with each `<!-- NAME table: ... -->` ... `<!-- end NAME table -->` block rendered anew."""
    for name, table in (("config", config.markdown_table()), ("info", info.markdown_table())):
        start = text.index("\n", text.index(f"<!-- {name} table: ")) + 1
        text = text[:start] + table + text[text.index(f"<!-- end {name} table -->"):]
    return text


def main(argv: list[str]) -> int:
    old = README.read_text()
    new = with_tables(old)
    if "--check" in argv:
        print("envs/README.md tables are " + ("up to date" if new == old else "stale: run scripts/env_tables.py"))
        return int(new != old)
    if new != old:
        write_text(README, new)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
