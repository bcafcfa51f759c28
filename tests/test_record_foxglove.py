"""A demo record read by the official TypeScript readers, as Foxglove reads it.

``tests/js/read_record.mjs`` opens the record with ``@mcap/core`` (indexed, CRCs checked) and
decodes the ROS 2 messages with ``@foxglove/rosmsg`` + ``@foxglove/rosmsg2-serialization``.
CI installs them with ``npm ci --prefix tests/js``; without ``tests/js/node_modules`` (or node)
the test skips.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from test_record_json_schemas import foxglove_problems

from cellguard.record.reader import open_record
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

JS = Path(__file__).parent / "js"

pytestmark = pytest.mark.skipif(
    shutil.which("node") is None or not (JS / "node_modules" / "@mcap" / "core").is_dir(),
    reason="the TypeScript MCAP readers are not installed: run `npm ci --prefix tests/js` (needs node 18+)")


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    # the demo's cell and policy, short, with a NaN chunk so that the envelope raises events
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 7, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 1, "faults": [{"kind": "policy_nan", "at_cycle": 1}]})
    before = time.time_ns()
    summary = run_scenario(scenario, out)
    after = time.time_ns()
    done = subprocess.run(["node", str(JS / "read_record.mjs"), str(out / "record.mcap")], capture_output=True,
                          text=True, timeout=300, check=True)
    return out, summary, json.loads(done.stdout), (before, after)


def test_first_log_time_is_the_runs_wall_clock_date(demo):
    out, _, seen, (before, after) = demo
    with open_record(out) as rec:
        epoch = rec.epoch_wall_ns
        first_t = rec.contexts[0].t_ns
    assert before <= epoch <= after  # the run's start, on the wall clock
    assert int(seen["firstLogTime"]) == epoch + first_t
    assert seen["ordered"]  # every message in log-time order, across chunks too


def test_joint_states_decode_with_names_and_real_dates(demo):
    out, _, seen, (before, after) = demo
    with open_record(out) as rec:
        joints = list(rec.context["embodiment"]["joints"])
        ticks = rec.ticks(rate="decimated")
    assert seen["topics"]["/joint_states"]["schema"] == "sensor_msgs/msg/JointState"
    assert seen["topics"]["/joint_states"]["count"] == len(ticks)
    first = seen["jointStates"][0]
    assert first["name"] == joints
    assert first["position"] == pytest.approx(ticks.q_meas[0], abs=1e-6)  # float32 in the batch, float64 here
    stamp_ns = first["stamp"]["sec"] * 10**9 + first["stamp"]["nanosec"]
    assert stamp_ns == int(first["logTime"]) and before <= stamp_ns <= after + 10**12


def test_events_decode_on_the_log_schema_with_level_by_stop_category(demo):
    _, summary, seen, _ = demo
    assert seen["topics"]["/events/log"]["schema"] == "rcl_interfaces/msg/Log"
    assert len(seen["logs"]) == min(50, len(summary["events"])) > 0
    levels = {e["kind"]: e.get("category") for e in summary["events"]}
    for log in seen["logs"]:
        kind = log["msg"].split("]")[0].lstrip("[")
        assert kind in levels
        want = {0: 50, 1: 40, 2: 30}.get(levels[kind])
        assert log["level"] == want if want is not None else log["level"] in (10, 20)


def test_the_robot_description_is_attached_and_moves_on_tf(demo):
    _, _, seen, _ = demo
    urdf = [a for a in seen["attachments"] if a["name"] == "robot_description.urdf"]
    assert urdf and urdf[0]["mediaType"] == "application/xml" and "<robot name=" in urdf[0]["head"]
    assert seen["topics"]["/robot_description"]["schema"] == "std_msgs/msg/String"
    assert ("upper_arm", "forearm") in {(t["parent"], t["child"]) for t in seen["tf"]}


def test_metadata_names_the_device_and_the_run(demo):
    out, summary, seen, _ = demo
    with open_record(out) as rec:
        context, record_id = rec.context, rec.record_id
    assert seen["metadata"]["foxglove"] == {"deviceName": f"{context['site']}/{context['cell_id']}",
                                            "key": record_id}
    facts = seen["metadata"]["cellguard"]
    assert facts["record_version"] == "2" and facts["record_id"] == record_id
    assert facts["policy_sha256"] == summary["context"]["policy_sha256"]
    assert facts["profile_sha256"] == summary["context"]["profile_sha256"]
    assert json.loads(seen["metadata"]["cellguard.context"]["context"]) == context


def test_json_channels_decode_and_their_schemas_load_in_foxglove(demo):
    """The schemas as the TypeScript reader sees them pass Foxglove's JSON-schema parser rule, and every event
    decoded holds only fields its schema declares, none of them null."""
    out, _, seen, _ = demo
    assert set(seen["jsonSchemas"]) == {"/context", "/events", "/cycles", "/measurements"}
    for topic, schema in seen["jsonSchemas"].items():
        assert foxglove_problems(schema, topic) == [] and seen["topics"][topic]["count"] > 0
    declared = set(seen["jsonSchemas"]["/events"]["properties"])
    with open_record(out) as rec:
        assert len(seen["events"]) == min(50, len(list(rec.events()))) > 0
    for event in seen["events"]:
        assert set(event) <= declared and None not in event.values()
