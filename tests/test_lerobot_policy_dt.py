"""A LeRobot policy's step period is the source's ``?dt=``: a saved policy states none, and the 20 ms once assumed
played a policy of another period too fast or too slow without a word. Runs in the LeRobot environment."""

from __future__ import annotations

import re

import pytest
import yaml

pytest.importorskip("torch")
pytest.importorskip("lerobot")

from foreign_arm import MAP, to_foreign  # noqa: E402
from small_act import save_small_act  # noqa: E402

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.registry import make_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402


@pytest.fixture(scope="module")
def act_dir(tmp_path_factory):
    folder = save_small_act(tmp_path_factory.mktemp("act"), to_foreign(ArmPickPlace().q_home), 30.0)
    (folder / "foreign.yaml").write_text(yaml.safe_dump(MAP))
    return folder


def test_a_lerobot_policy_without_dt_is_refused_naming_what_to_give(act_dir):
    refusal = (rf"^policy: lerobot:{re.escape(str(act_dir))}: the step period is not stated: give \?dt=SECONDS "
               rf"\(the policy's control period, e\.g\. 0\.0667 for 15 Hz\)$")
    with pytest.raises(ConfigError, match=refusal):
        make_policy(f"lerobot:{act_dir}?map={act_dir / 'foreign.yaml'}", ArmPickPlace())


def test_a_lerobot_policy_runs_at_the_period_given(act_dir):
    policy = make_policy(f"lerobot:{act_dir}?map={act_dir / 'foreign.yaml'}&dt=0.0333", ArmPickPlace())
    assert policy.dt_ns == 33_300_000
