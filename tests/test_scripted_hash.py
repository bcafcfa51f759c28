"""The scripted policies' content hash covers what determines their behaviour, not only their class source."""

from __future__ import annotations

import numpy as np

from cellguard.policy.scripted_arm import ScriptedArmPolicy
from cellguard.policy.scripted_quadruped import ScriptedQuadrupedPolicy
from cellguard.robot.registry import make_cell

ARM = make_cell("arm-pick-place")


def test_the_arm_programs_hash_changes_with_each_parameter_and_the_calibration():
    calibration = ARM.context()
    base = ScriptedArmPolicy(calibration=calibration).content_hash()
    assert ScriptedArmPolicy(calibration=calibration).content_hash() == base  # stable
    moved = {**calibration, "camera_calibration": {**calibration["camera_calibration"],
                                                   "position": list(np.add(calibration["camera_calibration"]
                                                                           ["position"], [0.001, 0.0, 0.0]))}}
    others = [ScriptedArmPolicy(calibration=calibration, vision_range=0.004),
              ScriptedArmPolicy(calibration=calibration, horizon=20),
              ScriptedArmPolicy(calibration=calibration, dt=0.01),
              ScriptedArmPolicy(calibration={**calibration, "fixture_datum": list(np.add(
                  calibration["fixture_datum"], [0.002, 0.0, 0.0]))}),
              ScriptedArmPolicy(calibration=moved)]
    hashes = [p.content_hash() for p in others]
    assert base not in hashes and len(set(hashes)) == len(hashes)


def test_the_gaits_hash_changes_with_each_parameter():
    profile = make_cell("quadruped-turns").profile
    base = ScriptedQuadrupedPolicy(profile).content_hash()
    hashes = [ScriptedQuadrupedPolicy(profile, **kw).content_hash()
              for kw in ({"period": 0.6}, {"duty": 0.5}, {"swing_height": 0.05}, {"horizon": 20})]
    assert base not in hashes and len(set(hashes)) == len(hashes)


def test_policies_close_as_a_no_op_by_default():
    policy = ScriptedArmPolicy(calibration=ARM.context())
    assert policy.close() is None  # inherited from Policy
