"""The sim-server wire against packets no healthy peer sends, over real UDP sockets on 127.0.0.1.

Server side (a real ``cellguard sim-server`` process): a hello starts a session, only its client
moves the robot, and every packet it does not act on is counted by reason and said on stderr
(once a second at most) while it keeps serving. Client side (the bridge against a stand-in
server in a thread): metadata or state packets of another shape are one line naming the field.
"""

from __future__ import annotations

import contextlib
import json
import socket
import sys
import threading
import time

import numpy as np
import pytest
import yaml
from sim_server_util import HOME, scenario, server_counters, start_server, sway_file

from cellguard.errors import CellguardError
from cellguard.release.plan import load_plan
from cellguard.robot.bridges.sim_server import COMMAND_HEAD, STATE_HEAD, Layout, SimServerRobot, pack_command
from cellguard.robot.protocol import RobotLinkError
from cellguard.runtime import Run
from cellguard.runtime.sim_server import CLIENT_LIVE_NS
from cellguard.scenario import parse_scenario

DOF = len(HOME)
NUDGED = HOME + np.array([0.05, 0, 0, 0, 0, 0])  # a setpoint the drives take as it is


@pytest.fixture
def server():
    proc, port = start_server()
    yield proc, port
    proc.kill()
    proc.wait()


def said(proc) -> str:
    """Everything the server wrote after its first line; it is stopped for this."""
    proc.kill()
    return proc.stdout.read()


class Peer:
    """A raw UDP socket on 127.0.0.1 speaking the sim-server's wire format: a client once it says hello."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(2.0)
        self.name = "%s:%d" % self.sock.getsockname()

    def hello(self) -> None:
        self.sock.send(b"H")
        while self.sock.recv(65536)[:1] != b"M":
            pass

    def command(self, seq: int, setpoint: np.ndarray) -> None:
        self.sock.send(pack_command(seq, time.monotonic_ns(), True, setpoint))

    def applied(self) -> tuple[int, np.ndarray]:
        """The command in force (its seq) and what the drives took, from a state sent after the commands so far."""
        self._newest_state()
        time.sleep(0.1)
        packet = self._newest_state()
        assert packet is not None, "no state from the server"
        body = np.frombuffer(packet, dtype="<f8", offset=STATE_HEAD.size)
        return STATE_HEAD.unpack_from(packet)[3], body[4 * DOF:5 * DOF]

    def counters(self) -> dict:
        self.sock.send(b"?")
        while (packet := self.sock.recv(65536))[:1] != b"R":
            pass
        return json.loads(packet[1:])

    def _newest_state(self) -> bytes | None:
        newest = None
        self.sock.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            while True:
                packet = self.sock.recv(65536)
                newest = packet if packet[:1] == b"S" else newest
        self.sock.settimeout(2.0)
        return newest


def test_a_hello_starts_a_session_whose_commands_count_from_one(server):
    """A second run against the same server: its seq 1, 2, ... were below the first run's last and all ignored.
    The first client went silent (a crashed run) and is taken over once it has been silent for a second."""
    proc, port = server
    first = Peer(port)
    first.hello()
    for seq in range(1, 51):
        first.command(seq, HOME)
    assert first.applied()[0] == 50
    time.sleep(CLIENT_LIVE_NS * 1e-9 + 0.1)
    second = Peer(port)
    second.hello()
    second.command(1, NUDGED)
    cmd_seq, applied = second.applied()
    assert cmd_seq == 1 and np.allclose(applied, NUDGED)
    assert second.counters()["stale_commands"] == 0
    lines = said(proc).splitlines()
    assert f"sim-server: client {first.name} said hello" in lines
    assert f"sim-server: client {second.name} said hello; commands from {first.name} are refused from now on" in lines


def test_a_hello_while_the_client_is_live_is_refused_and_a_goodbye_lets_the_next_client_in_at_once(server):
    """Any local peer's hello took the robot from a run still driving it (which then read a silent server)."""
    proc, port = server
    client, intruder = Peer(port), Peer(port)
    client.hello()
    client.command(1, NUDGED)
    intruder.sock.send(b"H")
    busy = intruder.sock.recv(65536)
    assert busy[:1] == b"B" and json.loads(busy[1:])["client"] == client.name
    with pytest.raises(RobotLinkError, match=f"is serving {client.name} \\(heard \\d+ ms ago\\)") as refused:
        SimServerRobot(("127.0.0.1", port))
    assert refused.value.kind == "robot_read_failed"
    client.command(2, HOME)
    cmd_seq, applied = client.applied()
    assert cmd_seq == 2 and np.allclose(applied, HOME)
    assert client.counters()["refused_hellos"] == 2
    client.sock.send(b"G")
    time.sleep(0.05)
    robot = SimServerRobot(("127.0.0.1", port))  # at once: no second of silence to wait out
    robot.close()
    intruder.hello()  # the bridge said goodbye when it closed
    out = said(proc)
    assert f"sim-server: refused a hello from {intruder.name}: client {client.name} is live" in out
    assert f"sim-server: client {client.name} said goodbye" in out
    assert "Traceback" not in out


def test_a_client_that_has_not_commanded_yet_stays_live_through_a_long_warm_up(server):
    """A run sends nothing while its policy loads and warms up: after a second it was taken over."""
    _, port = server
    client, intruder = Peer(port), Peer(port)
    client.hello()
    time.sleep(CLIENT_LIVE_NS * 1e-9 + 0.2)
    with pytest.raises(RobotLinkError, match=f"is serving {client.name} .* once its client has been silent for 30 s"):
        SimServerRobot(("127.0.0.1", port))
    client.command(1, NUDGED)
    assert client.applied()[0] == 1
    time.sleep(CLIENT_LIVE_NS * 1e-9 + 0.1)
    intruder.hello()  # once it has commanded, a second of silence is a gone client


def test_commands_from_a_peer_that_never_said_hello_are_refused_and_counted(server):
    """It moved the robot, and its seq 2^64-1 locked every client out."""
    proc, port = server
    client, stranger = Peer(port), Peer(port)
    client.hello()
    stranger.command(2**64 - 1, HOME + np.array([0.3, 0, 0, 0, 0, 0]))
    time.sleep(0.05)
    client.command(1, NUDGED)
    cmd_seq, applied = client.applied()
    assert cmd_seq == 1 and np.allclose(applied, NUDGED)
    counters = stranger.counters()  # anyone may ask for the counters
    assert counters["foreign_commands"] == 1 and counters["commands"] == 1
    assert (f"sim-server: refused a command from {stranger.name}: not the client (say hello first) "
            "(foreign_commands: 1)") in said(proc)


def test_every_packet_not_acted_on_is_counted_and_said_at_most_once_a_second_and_the_server_keeps_serving(server):
    """A short command crashed the server with a traceback; a wrong-length or unknown packet went without a word."""
    proc, port = server
    client = Peer(port)
    client.hello()
    malformed = [b"C", b"C" + bytes(10), COMMAND_HEAD.pack(b"C", 1, 0, 1) + bytes(7),
                 pack_command(1, 0, True, HOME[:-1]), b"", b"\xff" * 100]
    client.sock.send(b"C" + bytes(65000))
    for _ in range(10):  # in bursts the server's socket buffer holds
        for packet in malformed:
            client.sock.send(packet)
        time.sleep(0.005)
    client.command(5, NUDGED)
    client.command(4, HOME)  # older than the one in force
    client.command(6, np.full(DOF, np.nan))
    cmd_seq, applied = client.applied()
    assert proc.poll() is None and cmd_seq == 5 and np.allclose(applied, NUDGED)
    counters = client.counters()
    assert (counters["malformed_packets"], counters["stale_commands"], counters["nonfinite_commands"]) == (61, 1, 1)
    out = said(proc)
    assert "Traceback" not in out
    notes = [line for line in out.splitlines() if "said hello" not in line]
    assert notes == ["sim-server: dropped a command of 65001 bytes, expected 66 (6 joints) (malformed_packets: 1)",
                     "sim-server: ignored command 4: not newer than command 5 in force (stale_commands: 1)",
                     "sim-server: refused command 6: a setpoint value is not finite (nonfinite_commands: 1)"]


def test_a_finite_setpoint_outside_a_joints_range_is_refused_and_the_robot_holds(server):
    """The elbow at 10 rad was driven past its limit at full torque; at 1e11 MuJoCo zeroed every control and all six
    joints fell toward zero. A controller refuses a target beyond a joint's range."""
    proc, port = server
    client = Peer(port)
    client.hello()
    client.command(1, NUDGED)
    for seq, elbow in enumerate((10.0, 1e11, -1e300), start=2):
        client.command(seq, np.where(np.arange(DOF) == 2, elbow, HOME))
    cmd_seq, applied = client.applied()
    assert cmd_seq == 1 and np.allclose(applied, NUDGED)
    client.command(5, HOME)  # a good command after them is taken
    cmd_seq, applied = client.applied()
    assert cmd_seq == 5 and np.allclose(applied, HOME)
    assert client.counters()["out_of_range_commands"] == 3
    out = said(proc)
    assert "WARNING" not in out and "sim-server: refused command 2: elbow setpoint 10 is 7.5 past its upper limit 2.5" \
        in out


@pytest.mark.parametrize("excess", [1e-9, np.nan])
def test_a_power_off_is_taken_even_with_a_setpoint_the_drives_refuse(excess):
    """The range check refused the whole command, power-off included: the drives stayed powered; and a value a
    nanoradian past the limit was printed as the limit itself."""
    from cellguard.runtime.sim_server import SimServer

    server = SimServer("arm-pick-place", port=0)
    try:
        server.client = ("127.0.0.1", 9)
        q = np.asarray(server.cell.read().q, dtype=float)
        server._command(pack_command(1, 0, True, q), server.client)
        bad = q.copy()
        bad[2] = server.cell.profile.q_max[2] + excess
        server._command(pack_command(2, 0, False, bad), server.client)
        assert server._power is False and server._cmd_seq == 1  # the stop taken, the setpoint not
        server._command(pack_command(3, 0, True, bad), server.client)
        assert server._power is False  # a bad setpoint never powers the drives on
    finally:
        server.sock.close()


def test_floods_of_hellos_and_counter_queries_neither_fill_the_log_nor_get_an_answer_each(server):
    """16,863 'said hello' lines (1.6 MB) in a minute; answers to other peers' floods slowed the client's states."""
    proc, port = server
    client, other = Peer(port), Peer(port)
    for _ in range(200):
        client.hello()
        client.sock.send(b"G")
    other.sock.settimeout(0.2)
    answers = 0
    for _ in range(200):
        other.sock.send(b"?")
    with contextlib.suppress(TimeoutError):
        while other.sock.recv(65536)[:1] == b"R":
            answers += 1
    client.hello()
    assert client.counters()["sessions"] == 201
    assert answers <= 20
    out = said(proc).splitlines()
    assert 1 <= sum("said hello" in line for line in out) <= 10 and sum("said goodbye" in line for line in out) <= 10


# -- the bridge against a stand-in server --------------------------------------------------------------------------


class FakeServer:
    """A stand-in for the sim-server on a real loopback socket, in a thread: it answers a hello with ``metadata``
    and then sends the client ``state(seq)`` every millisecond."""

    def __init__(self, metadata: bytes, state):
        self.metadata, self.state = metadata, state
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.001)
        self.address = self.sock.getsockname()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        client, seq = None, 0
        while not self._done.is_set():
            with contextlib.suppress(TimeoutError):
                packet, addr = self.sock.recvfrom(65536)
                if packet[:1] == b"H":
                    client = addr
                    self.sock.sendto(b"M" + self.metadata, addr)
            if client is not None:
                seq += 1
                with contextlib.suppress(OSError):
                    self.sock.sendto(self.state(seq), client)

    def close(self) -> None:
        self._done.set()
        self._thread.join()
        self.sock.close()


@pytest.fixture(scope="module")
def metadata() -> dict:
    """The metadata a real server of the arm cell sends."""
    from cellguard.runtime.sim_server import SimServer

    served = SimServer("arm-pick-place", 0)
    served.sock.close()
    return served.meta


def state_packet(metadata: dict, seq: int, tail=(0.0, -1.0, 0.0)) -> bytes:
    """A state packet at the home pose; ``tail``: cycle_done, safety_stop, reduced_speed."""
    body = np.zeros(Layout(DOF, metadata["measurements"]).size)
    body[:DOF], body[-3:] = HOME, tail
    return STATE_HEAD.pack(b"S", seq, time.monotonic_ns(), 0) + body.astype("<f8").tobytes()


@contextlib.contextmanager
def fake_server(metadata, state):
    served = FakeServer(metadata if isinstance(metadata, bytes) else json.dumps(metadata).encode(), state)
    try:
        yield served
    finally:
        served.close()


@pytest.mark.parametrize("edit, says", [
    (lambda m: b"{not json", "metadata must be a JSON object, got b'{not json'"),
    (lambda m: [1, 2, 3], "metadata must be a JSON object"),
    (lambda m: b"[" * 30000 + b"]" * 30000, "metadata must be a JSON object"),  # a RecursionError traceback
    (lambda m: {k: v for k, v in m.items() if k != "cell"}, "cell must be a cell name, got nothing"),
    (lambda m: {**m, "dt_ns": 0}, "dt_ns must be the servo period, an integer 10^6 to 10^9 [ns] (1 kHz to 1 Hz), "
                                  "got 0"),
    (lambda m: {**m, "dt_ns": 1}, "dt_ns must be the servo period, an integer 10^6 to 10^9 [ns] (1 kHz to 1 Hz), "
                                  "got 1"),
    (lambda m: {**m, "dt_ns": 999_999}, "dt_ns must be the servo period, an integer 10^6 to 10^9 [ns]"),
    (lambda m: {**m, "dt_ns": "fast"}, "dt_ns must be"),
    (lambda m: {**m, "measurements": "abc"}, "measurements must be {name: size}"),
    (lambda m: {**m, "measurements": {"part_in_camera": -9}}, "measurements must be {name: size}"),
    (lambda m: {**m, "q_home": [0.0, 0.1]}, "q_home must be 6 finite joint positions, got [0.0, 0.1]"),
    (lambda m: {**m, "q_home": [*HOME[:2], float("nan"), *HOME[3:]]}, "q_home must be 6 finite joint positions"),
    (lambda m: {**m, "q_home": [*HOME[:2], 9.0, *HOME[3:]]},
     "q_home must be within the joint limits, elbow within [-2.5, 2.5], got 9.0"),
    (lambda m: {**m, "q_home": [*HOME[:5], 0.0059]}, "q_home must be within the joint limits, gripper within "
                                                     "[0.006, 0.029], got 0.0059"),
], ids=["not-json", "a-list", "nested-30000-deep", "no-cell", "dt-zero", "dt-one", "dt-under-1ms", "dt-text", "measurements-text",
        "measurement-negative", "home-short", "home-nan", "home-beyond-a-limit", "home-under-a-limit"])
def test_metadata_of_another_shape_is_one_error_naming_the_field(metadata, edit, says):
    """Tracebacks before (KeyError, ZeroDivisionError later in the tracker; a period of 1 ns a MemoryError sizing
    the loop's cycle buffer); a short home pose crashed the retreat at the end of the run and lost summary.json, a
    NaN one skipped it, one beyond a joint's limits was clamped without a word."""
    with fake_server(edit(metadata), lambda seq: state_packet(metadata, seq)) as served:
        with pytest.raises(RobotLinkError) as refused:
            SimServerRobot(served.address).close()
    assert refused.value.kind == "robot_read_failed"
    assert f"sim-server at 127.0.0.1:{served.address[1]} sent bad metadata: {says}" in str(refused.value)


@pytest.mark.parametrize("bad, says", [
    (lambda packet: packet[:3], "state packet of 3 bytes, expected 337 (39 values)"),
    (lambda packet: packet + b"\x00\x01\x02", "state packet of 340 bytes, expected 337"),
    (lambda packet: packet[:-16] + np.array([np.nan, 0.0]).tobytes(), "safety_stop nan"),
    (lambda packet: packet[:-16] + np.array([np.inf, 0.0]).tobytes(), "safety_stop inf"),
    (lambda packet: packet[:-16] + np.array([7.0, 0.0]).tobytes(), "safety_stop 7.0"),
    (lambda packet: packet[:-24] + np.array([np.nan, -1.0, 0.0]).tobytes(), "cycle_done nan"),
], ids=["truncated-head", "odd-length", "stop-nan", "stop-inf", "stop-7", "cycle-done-nan"])
def test_a_state_packet_of_another_shape_is_a_read_fault(metadata, bad, says):
    """At connect and mid-run: struct.error, 'buffer size must be a multiple', int(nan) were tracebacks."""
    broken = threading.Event()
    with fake_server(metadata, lambda seq: (bad if broken.is_set() else bytes)(state_packet(metadata, seq))) as served:
        robot = SimServerRobot(served.address, read_timeout_s=1.0)
        broken.set()
        try:
            with pytest.raises(RobotLinkError) as mid_run:
                for _ in range(1000):
                    robot.read()
                    time.sleep(0.001)
        finally:
            robot.close()
        with pytest.raises(RobotLinkError) as at_connect:
            SimServerRobot(served.address).close()
    for refused in (mid_run, at_connect):
        assert refused.value.kind == "robot_read_failed" and says in str(refused.value)


@pytest.mark.parametrize("edit, says", [({"dt_ns": 0}, "dt_ns must be"), ({"dt_ns": 1}, "dt_ns must be"),
                                         ({"q_home": [*HOME[:2], 9.0, *HOME[3:]]}, "q_home must be within")],
                         ids=["dt-zero", "dt-one", "home-beyond-a-limit"])
def test_bad_metadata_is_one_line_and_exit_2(metadata, edit, says, tmp_path):
    """A period of 1 ns was a MemoryError traceback (exit 1); a home pose beyond a limit ran, its retreat clamped."""
    from typer.testing import CliRunner

    from cellguard.cli import app

    with fake_server({**metadata, **edit}, lambda seq: state_packet(metadata, seq)) as served:
        path = tmp_path / "s.yaml"
        path.write_text(f"cell: arm-pick-place\nrobot: sim-server:udp://127.0.0.1:{served.address[1]}\n"
                        "cycle: {source: time, seconds: 1}\n")
        result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("error: sim-server at 127.0.0.1:") and says in result.stderr
    assert result.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()  # refused before anything ran or was recorded


def test_a_run_refused_after_it_connected_lets_the_next_one_in_at_once(server, tmp_path):
    """A policy that cannot be loaded (or a cycle source the robot cannot serve) ended the run after its hello,
    without a goodbye: the corrected run was refused for the 30 s a starting client is held."""
    _, port = server
    with pytest.raises(CellguardError, match="no such file"):
        Run(parse_scenario(scenario(port, tmp_path / "missing.npz")))
    SimServerRobot(("127.0.0.1", port)).close()  # at once, not busy


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the closed port is read from Linux's error queue")
def test_a_client_whose_process_died_before_its_first_command_is_gone_at_once(server):
    """A run that crashed during its policy's warm-up held the robot for 30 s; a stranger who leaves does not
    end the client's session."""
    proc, port = server
    client, stranger = Peer(port), Peer(port)
    client.hello()
    stranger.sock.send(b"H")
    stranger.sock.close()  # the server's refusal comes back port-unreachable
    time.sleep(0.1)
    assert client.counters()["refused_hellos"] == 1  # still the client: the stranger's closed port did not end it
    client.sock.close()
    time.sleep(0.1)
    SimServerRobot(("127.0.0.1", port)).close()  # at once, not after 30 s
    out = said(proc)
    assert f"sim-server: client {client.name} is gone (its port is closed)" in out and "Traceback" not in out


@pytest.mark.parametrize("key, value", [("faults", [{"kind": "friction_step", "at_cycle": 0, "joint": "elbow",
                                                      "factor": 2.0}]),
                                         ("process_changes", [{"kind": "payload", "at_cycle": 0, "grams": 40.0}])])
def test_simulation_only_changes_on_a_bridge_are_refused(tmp_path, key, value):
    """A payload change on a sim-server robot was accepted: never applied, yet listed as ground truth. Refused as
    the scenario is read, no server needed."""
    body = {**scenario(9, sway_file(tmp_path / "s.npz")), key: value}
    with pytest.raises(CellguardError, match=f"{key}: applied to simulated cells only"):
        parse_scenario(body)


def test_a_release_plan_with_faults_on_a_bridge_is_refused_as_it_is_read(tmp_path):
    """Such a run was refused only as it started: the stage's earlier runs had run by then."""
    fault = {"kind": "friction_step", "at_cycle": 0, "joint": "elbow", "factor": 2.0}
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({"stages": {"bench": {
        "runs": [{"name": "first"}, {"name": "r", "robot": "sim-server:tcp://127.0.0.1:9", "faults": [fault]}],
        "gates": [{"metric": "protective_stops", "max": 0}]}}}))
    with pytest.raises(CellguardError, match=r"stages.bench.runs\[1\]: faults: applied to simulated cells only"):
        load_plan(plan)



def test_a_cycle_a_former_client_left_under_way_is_not_the_new_clients_first_cycle(server):
    """A run stopped mid-cycle (its retreat aborted) left the arm away from home: the next run's approach brought
    it home, the cell's task ended the old cycle there and the new run counted a success it never worked for."""
    _, port = server
    away = HOME + np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    first = Peer(port)
    first.hello()
    for seq in range(1, 401):  # 0.4 s of commands: the arm leaves home
        first.command(seq, away)
        time.sleep(0.001)
    first.sock.send(b"G")
    second = Peer(port)
    second.hello()
    for seq in range(1, 1501):  # 1.5 s: back home and still, where the old cycle would end
        second.command(seq, HOME)
        time.sleep(0.001)
    assert server_counters(port)["cycles"] == 0  # asked from another socket: the client's is full of states
