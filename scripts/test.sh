#!/usr/bin/env bash
# The tests: install the test extra (`dev`: pytest, hypothesis, scipy, SUMO's netconvert) into
# .venv, then run pytest (arguments go to pytest). The rl and ray tests skip with a reason unless
# those extras are installed (`bash scripts/setup.sh dev,rl,ray,search`, as CI does).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh dev
export SDL_VIDEODRIVER=offscreen MPLBACKEND=Agg
# pytest's default output: a line per test file with its dots and the percentage done (a CI log
# shows where a long run is); -ra (pyproject.toml) lists every skip's reason at the end
exec .venv/bin/python -m pytest "$@"
