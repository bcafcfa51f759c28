#!/usr/bin/env bash
# The official TypeScript MCAP readers for tests/test_record_foxglove.py (node 18+); run before pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
if command -v npm >/dev/null 2>&1; then
  npm ci --prefix tests/js --no-audit --no-fund --loglevel=error
else
  echo "npm not found: tests/test_record_foxglove.py will skip"
fi
