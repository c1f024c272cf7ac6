#!/usr/bin/env bash
# The main job on a fresh machine: install, generate the paper's M1 map, export it to Apollo
# and OpenDRIVE, and drive it headless with the baseline planner. Outputs land in out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export SDL_VIDEODRIVER=offscreen MPLBACKEND=Agg
.venv/bin/python examples/demo.py --out out/demo "$@"
