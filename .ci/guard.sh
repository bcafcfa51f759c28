#!/usr/bin/env bash
# Guard checks for CI (after the main install in .ci/run): layer contract, mutation check, soak figures.
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/lint-imports
.venv/bin/python tests/mutations/run.py --jobs 2
.venv/bin/python benchmarks/soak.py --hours 24
