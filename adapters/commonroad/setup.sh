#!/usr/bin/env bash
# The CommonRoad reactive planner's own venv (.venv-crplanner at the repository root), from the
# package registry: commonroad-reactive-planner 2025.1 pulls commonroad-io 2024.3 and protobuf 3.20,
# which feat2map's venv cannot hold, so it lives apart and talks to feat2map through the planner
# bridge (docs/planners.md). Idempotent: does nothing when the venv already has the pinned planner.
# PYTHON picks the interpreter (3.10-3.12; default python3).
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PYTHON:-python3}
VENV=${CRPLANNER_VENV:-.venv-crplanner}
PINS=("commonroad-reactive-planner==2025.1" "commonroad-route-planner==2025.1.0" "coverage>=7.4")
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" - <<'PYEOF' 2>/dev/null
import importlib.metadata as md
assert md.version("commonroad-reactive-planner") == "2025.1"
assert md.version("commonroad-route-planner") == "2025.1.0"
import commonroad_rp.reactive_planner, commonroad_route_planner.route_planner, coverage  # noqa: F401
PYEOF
then
  exit 0
fi
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q "${PINS[@]}"
"$VENV/bin/python" -c "import commonroad_rp.reactive_planner, commonroad_route_planner.route_planner"
echo "$VENV: commonroad-reactive-planner 2025.1 ready"
