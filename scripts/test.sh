#!/usr/bin/env bash
# The tests: install the test extra (`dev`: pytest, hypothesis, scipy, SUMO's netconvert) into
# .venv, then run pytest (arguments go to pytest). The rl and ray tests skip with a reason unless
# those extras are installed (`bash scripts/setup.sh dev,rl,ray`, as CI does).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh dev
export SDL_VIDEODRIVER=offscreen MPLBACKEND=Agg
exec .venv/bin/python -m pytest -q "$@"
