#!/usr/bin/env bash
# The static checks CI runs: ruff (pycodestyle, pyflakes, bugbear) over the repository and mypy
# over the package, both with their settings in pyproject.toml. Needs the dev extra
# (`bash scripts/setup.sh dev`); exits non-zero on the first checker that finds anything.
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/ruff check .
.venv/bin/mypy
