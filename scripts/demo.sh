#!/usr/bin/env bash
# The main job on a fresh machine: install, generate the paper's M1 map, export it to Apollo
# (validated) and OpenDRIVE, build its route-coverage suite and drive every route headless with
# the baseline planner, then one drive through the Python API with a rendered frame.
# Outputs land in out/demo/ (open out/demo/rollout/report.md and the PNGs).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh   # only the main job's dependencies (no test, rl or ray extras)
export SDL_VIDEODRIVER=offscreen MPLBACKEND=Agg
f2m=.venv/bin/feat2map
out=out/demo
$f2m generate --seed 1 --opendrive --out $out/m1            # map.json, features.json, map.png, junctions.png, map.xodr, apollo/
$f2m validate $out/m1/apollo                               # Apollo's rules: 0 problems
$f2m suite $out/m1/map.json --traffic 6 --pedestrian-rate 4 --name m1 --out $out/suite.yaml   # every (junction, entry, exit) manoeuvre, few routes (beside m1/: a generated folder holds only what generate wrote, so the demo runs again)
$f2m rollout $out/suite.yaml --workers 2 --fail-on none --out $out/rollout   # report.md, report.html, junit.xml, summary.json, GIFs of failures (CI uses --fail-on any)
.venv/bin/python examples/demo.py --map $out/m1/map.json --out $out
