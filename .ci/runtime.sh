#!/usr/bin/env bash
# The runtime's figures for CI: the real-time loop against sim-server (short run) and inference workers.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
"$PY" benchmarks/realtime.py --seconds 20
"$PY" benchmarks/inference.py --seconds 3 --busy
