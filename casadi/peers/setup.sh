#!/usr/bin/env bash
# Installs the performance peers' extra pins (scipy) into casadi/.venv, which
# casadi/run.sh creates with casadi and numpy.
set -euo pipefail
cd "$(dirname "$0")/../.."
[[ -x casadi/.venv/bin/python ]] || bash casadi/run.sh
casadi/.venv/bin/python -m pip install --disable-pip-version-check --quiet -r casadi/peers/requirements.txt
casadi/.venv/bin/python -c 'import casadi, scipy; print("casadi", casadi.__version__, "scipy", scipy.__version__)'
