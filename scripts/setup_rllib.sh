#!/usr/bin/env bash
# RLlib's own venv (.venv-rllib at the repository root): ray[rllib] 2.60 pins gymnasium 1.2.2 while
# the project's venv runs gymnasium 1.4, so RLlib gets a venv of its own holding feat2map (editable,
# the rl extra) next to it; tests/envs/test_vector_rllib.py runs its PPO smoke test there. Idempotent.
# PYTHON picks the interpreter (default python3).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${RLLIB_VENV:-.venv-rllib}
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "import ray.rllib, feat2map" 2>/dev/null; then
  exit 0
fi
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q torch==2.13.0  # CPU torch, as scripts/setup.sh pins it
"$VENV/bin/python" -m pip install -q -e ".[rl]" "ray[rllib]==2.60.0" pytest
"$VENV/bin/python" -c "import ray.rllib, feat2map"
echo "$VENV: ray[rllib] 2.60.0 ready"
