#!/usr/bin/env bash
# The static checks CI runs: ruff (pycodestyle, pyflakes, bugbear) over the repository and mypy
# over the package, envs/ and scenarios/ included, both with their settings in pyproject.toml.
# Needs the dev extra (`bash scripts/setup.sh dev`); exits non-zero on the first checker that
# finds anything.
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/ruff check .
# envs/ and scenarios/ are the packages feat2map.envs and feat2map.scenarios (pyproject.toml's
# package-dir), which mypy cannot map from their folders: link them into a feat2map/ package
# under build/mypy/ (mypy's `files` lists those links; its errors name them by these paths)
mkdir -p build/mypy/feat2map
: > build/mypy/feat2map/__init__.py  # only makes the folder a package: feat2map itself is ./feat2map
ln -sfn ../../../envs build/mypy/feat2map/envs
ln -sfn ../../../scenarios build/mypy/feat2map/scenarios
.venv/bin/mypy
