"""LeRobot adapter: a real ACT policy built from its config with random weights (no hub download),
saved with its processors, loaded through ``lerobot:DIR`` and run in the arm cell's tick path.

Runs only where LeRobot is installed (its own CI step: it brings torch)."""

import numpy as np
import pytest
import yaml

torch = pytest.importorskip("torch")
pytest.importorskip("lerobot")

from foreign_arm import MAP, to_foreign  # noqa: E402

from small_act import save_small_act  # noqa: E402

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402
from cellguard.runtime import Run  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402


@pytest.fixture(scope="module")
def act_dir(tmp_path_factory):
    """A small ACT (state + environment state in, 50-step chunks out) trained on a foreign arm's units."""
    folder = save_small_act(tmp_path_factory.mktemp("act"), to_foreign(ArmPickPlace().q_home), 30.0,
                            dim_model=128, n_encoder_layers=2)
    (folder / "foreign.yaml").write_text(yaml.safe_dump(MAP))
    return folder


def test_act_policy_runs_the_arm_cell_through_the_tick_path(act_dir):
    scenario = parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0,
                               "policy": f"lerobot:{act_dir}?map={act_dir / 'foreign.yaml'}&dt=0.02"})
    run = Run(scenario)
    outcome = run.cycle()
    assert outcome["inference"]["chunks"] > 50 and outcome["inference"]["wall_ms_mean"] > 0
    assert run.ticks.n > 0
    assert (run.ticks.rows("setpoint") >= run.cell.profile.q_min).all()
    assert (run.ticks.rows("setpoint") <= run.cell.profile.q_max).all()
    assert not any(e.kind == "chunk_rejected" for e in run.events)
    # Random weights around home: the arm stays within a few degrees of home, mapped from the foreign units.
    assert np.abs(run.ticks.rows("setpoint")[:, :5] - run.cell.q_home[:5]).max() < 0.2


def test_a_chunk_comes_back_in_robot_joints_and_stamped(act_dir):
    cell = ArmPickPlace()
    policy = make_policy(f"lerobot:{act_dir}?map={act_dir / 'foreign.yaml'}&dt=0.02", cell)
    obs = cell.observe()
    chunk = policy.infer(obs)
    assert chunk.actions.shape == (50, 6) and chunk.t_obs_ns == obs.t_ns
    assert policy.latencies_ns[-1] > 0


def test_missing_folder_and_wrong_dimension_are_named(act_dir, tmp_path):
    cell = ArmPickPlace()
    with pytest.raises(ConfigError, match="no config.json"):
        make_policy(f"lerobot:{tmp_path}", cell)
    short = {**MAP, "actions": MAP["actions"][:5], "hold": {"shoulder_pan": "0 rad"}}
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(short))
    with pytest.raises(ConfigError, match="outputs 6 actions per step, the map declares 5"):
        make_policy(f"lerobot:{act_dir}?map={path}", cell)
