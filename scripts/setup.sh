#!/usr/bin/env bash
# Create .venv and install feat2map (idempotent). With no argument: only what the main job needs
# (generate, export, validate, suites, rollouts, the demo). With a comma-separated list of extras
# (pyproject.toml): also those, e.g. `bash scripts/setup.sh dev` for the tests (and CommonRoad export),
# `bash scripts/setup.sh commonroad` for the CommonRoad export,
# `bash scripts/setup.sh search` for `feat2map search` (Optuna; `dev` includes it),
# `bash scripts/setup.sh dev,rl,ray,search` for everything (CI).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
extras=${1:-}
step() { echo "setup: $*"; }  # a line per step: pip -q is silent for a minute at a time
# setuptools warns at every editable install that a folder named like the package in the working
# directory may shadow it; that is the README's note (run from the repository root, not from the
# folder holding a clone named feat2map), so the warning is filtered by its message here
export PYTHONWARNINGS="ignore:Editable installation"
if [ ! -x .venv/bin/python ]; then
  step "creating .venv with $PY"
  "$PY" -m venv .venv
fi
step "upgrading pip in .venv"
.venv/bin/python -m pip install -q --upgrade pip
if [[ ",$extras," == *",rl,"* ]]; then
  # CPU torch first, pinned, so resolving the rl extra never pulls a multi-GB CUDA build
  step "installing CPU torch 2.13.0 into .venv (the rl extra; about half a minute the first time)..."
  .venv/bin/python -m pip install -q torch==2.13.0  # the newest CPU build here (2.14/2.15: CUDA wheels only)
fi
step "installing feat2map${extras:+ with the extras $extras} and its dependencies into .venv (editable; about a minute)..."
.venv/bin/python -m pip install -q -e ".${extras:+[$extras]}"
if [[ ",$extras," == *",commonroad,"* || ",$extras," == *",dev,"* ]]; then
  # commonroad-io pins protobuf==3.20 (Apollo needs newer); feat2map uses only its XML modules:
  # installed without its pins into .venv/commonroad-io, off sys.path (feat2map adds it when it
  # imports commonroad), so `pip check` stays clean
  step "installing commonroad-io into .venv/commonroad-io (without its pins)..."
  .venv/bin/python -m pip uninstall -q -y commonroad-io 2>/dev/null || true  # an older setup's copy
  .venv/bin/python -m pip install -q --no-deps --upgrade --target .venv/commonroad-io 'commonroad-io>=2026.1,<2027'
fi
if [[ ",$extras," == *",dev,"* ]]; then
  # ASAM's checkers (the OpenDRIVE/OpenSCENARIO exports' tests, `feat2map validate` of .xodr/.xosc)
  # pin numpy<2 and lxml<6: they get their own environment, their commands linked into .venv/bin
  step "installing ASAM's OpenDRIVE and OpenSCENARIO checkers into .venv-qc..."
  [ -x .venv-qc/bin/python ] || "$PY" -m venv .venv-qc
  .venv-qc/bin/python -m pip install -q asam-qc-opendrive==1.0.0 asam-qc-openscenarioxml==1.0.0
  for b in qc_opendrive qc_openscenario; do ln -sf "$PWD/.venv-qc/bin/$b" ".venv/bin/$b"; done
fi
step "done: .venv is ready (source .venv/bin/activate, or .venv/bin/feat2map)"
