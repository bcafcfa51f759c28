"""The record states the action map in force and the embodiment profile's values, not only hashes: two runs of one
model under a map in rad and one in deg had identical contexts and stamps (the policy's hash covered the model file
only), and a technician could not see the limits the guard enforced without the profile file."""

from __future__ import annotations

import copy
import json
import math
from functools import partial

import numpy as np
import pytest

from cellguard.embodiment.action_map import parse_action_map
from cellguard.policy.adapter import MappedPolicy
from cellguard.record.context import build_context, versions
from cellguard.record.reader import open_record
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper")
MAP_RAD = {"robot": "arm-pick-place",
           "actions": [{"name": f"a{i}", "joint": j, "unit": "m" if j == "gripper" else "rad"}
                       for i, j in enumerate(JOINTS)]}
MAP_DEG = copy.deepcopy(MAP_RAD)
MAP_DEG["actions"][4]["unit"] = "deg"  # wrist_roll: the one change between the probe's two maps
MAP_DEG_SCALED = copy.deepcopy(MAP_RAD)
MAP_DEG_SCALED["actions"][4].update(unit="1", scale="1 deg")  # the same map, spelt otherwise


class Hold:
    """A model that answers the state it is given: the arm holds still under any map."""

    action_dim, action_names, embedded_map = 6, None, None

    def infer(self, inputs):
        return np.repeat(inputs.state[None, :], 25, axis=0)

    def reset(self):
        pass

    def content_hash(self):
        return "1" * 64  # one model for every map


def _policy(raw: dict) -> MappedPolicy:
    arm = ArmPickPlace()
    return MappedPolicy(Hold(), parse_action_map(raw, arm.profile), arm, "test:hold", 0.02)


SCENARIO = {"cell": "arm-pick-place", "seed": 2, "acceptance_cycles": 0, "production_cycles": 1,
            "cycle": {"source": "time", "seconds": 0.2}}


def _context(raw: dict | None) -> dict:
    run = Run(parse_scenario(SCENARIO), policy_factory=None if raw is None else partial(_policy, raw))
    return build_context(scenario=run.scenario, cell=run.cell, policy=run.policy, envelope=run.guard.envelope,
                         software={})


def test_two_maps_of_one_model_read_as_two_policies():
    rad, deg = _context(MAP_RAD), _context(MAP_DEG)
    assert rad["policy"]["sha256"] == deg["policy"]["sha256"]  # the model is the same
    assert versions(rad)["policy_version"] != versions(deg)["policy_version"]
    wrist = deg["policy"]["action_map"]["actions"][4]
    assert wrist["joint"] == "wrist_roll" and wrist["si_per_unit"] == pytest.approx(math.pi / 180)
    assert rad["policy"]["action_map"]["actions"][4]["si_per_unit"] == 1.0
    assert rad["policy"]["action_map"]["resolved_sha256"] != deg["policy"]["action_map"]["resolved_sha256"]


def test_two_spellings_of_one_map_read_as_one_policy():
    assert _context(MAP_DEG)["policy"] == _context(MAP_DEG_SCALED)["policy"]


def test_a_policy_without_a_map_keeps_the_policy_context_it_had():
    """A scripted policy has no map: its policy stamp reads as in a record written before the map was added."""
    assert sorted(_context(None)["policy"]) == ["sha256", "source"]


def test_the_context_holds_the_profile_document_that_embodiment_show_prints():
    context = _context(None)
    profile = ArmPickPlace().profile
    assert context["embodiment"]["profile"] == profile.to_dict()
    shown = {j["name"]: j for j in json.loads(json.dumps(context))["embodiment"]["profile"]["joints"]}
    assert shown["shoulder_pan"]["position"] == [-2.5, 2.5]
    assert {"velocity", "acceleration", "jerk", "effort"} <= shown["elbow"].keys()


def test_the_profile_document_leaves_the_calibration_stamp_as_older_records_have_it():
    """The document is the profile its sha256 names: a record made before it was recorded, of the same profile,
    keeps the same calibration stamp (the fleet groups findings by it)."""
    context = _context(None)
    older = {**context, "embodiment": {k: v for k, v in context["embodiment"].items() if k != "profile"}}
    assert versions(older)["calibration_version"] == versions(context)["calibration_version"]


def test_a_record_states_the_map_and_profile_in_force(tmp_path):
    stamps = {}
    for name, raw in (("rad", MAP_RAD), ("deg", MAP_DEG)):
        run_scenario(parse_scenario(SCENARIO), tmp_path / name, policy_factory=partial(_policy, raw))
        with open_record(tmp_path / name) as rec:
            context = rec.context
            stamps[name] = {c.versions["policy_version"] for c in rec.cycles()}
        assert context["policy"]["action_map"] == _policy(raw).map_document
        assert context["embodiment"]["profile"]["joints"][0]["position"] == [-2.5, 2.5]
    assert len(stamps["rad"]) == len(stamps["deg"]) == 1 and stamps["rad"] != stamps["deg"]
