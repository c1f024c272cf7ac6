#!/usr/bin/env bash
# The tests: install the test extra (`dev`: pytest, hypothesis, scipy, SUMO's netconvert) into
# .venv, then run pytest (arguments go to pytest). The rl and ray tests skip with a reason unless
# those extras are installed (`bash scripts/setup.sh dev,rl,ray,search`, as CI does).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh dev
export SDL_VIDEODRIVER=offscreen MPLBACKEND=Agg
# pytest-xdist runs the test files on every core (-n auto; FEAT2MAP_TEST_WORKERS=1 runs them in this
# process), a file's tests in one worker so that its module fixtures are built once; the output is
# a line of dots per 72 tests with the percentage done (a CI log shows where a long run is); -ra
# (pyproject.toml) lists every skip's reason at the end
workers="${FEAT2MAP_TEST_WORKERS:-auto}"
if [ "$workers" = 1 ]; then exec .venv/bin/python -m pytest "$@"; fi
exec .venv/bin/python -m pytest -n "$workers" --dist loadfile "$@"
