"""The sim-server bridge: a simulated cell in another process, reached over UDP on 127.0.0.1.

Wire format (little-endian). The client says hello (``H``); the server answers with its
metadata as JSON (``M``: cell, seed, joints, dt_ns, measurement sizes, home pose) and from then
on sends one state packet per servo period to that client; the client sends one command
packet per tick. Every packet has a sequence number and a monotonic timestamp [ns] (both
processes read the same CLOCK_MONOTONIC), so the client counts lost packets and sees stale
state. A hello starts a session: the server takes commands from that client only, and their
sequence starts again; while that client is live, another peer's hello is answered ``B`` (busy,
the client's address as JSON), and the client's goodbye (``G``) ends the session. A ``?`` asks
the server for its counters (commands received; packets refused: non-finite, stale, from a peer
that is not the client, malformed; hellos refused).

    state   b"S" seq:u64 t_ns:i64 cmd_seq:u64  then float64: q, qd, effort, current, sent (dof each),
            measurements (concatenated), cycle_done (0/1), safety_stop (-1: none, else the stop category
            0-2), reduced_speed (0/1)
    command b"C" seq:u64 t_ns:i64 power:u8     then float64: setpoint (dof)

The profile, forward kinematics and home pose come from the registered cell's own model (a
robot's kinematic model is known to its controller); the state comes only over the wire. The
served cell must be the one the scenario names.
"""

from __future__ import annotations

import contextlib
import functools
import json
import re
import socket
import struct
import time

import numpy as np

from cellguard.errors import ScenarioError
from cellguard.robot.protocol import RobotLinkError, SafetyInputs
from cellguard.robot.state import Observation, State

STATE_HEAD = struct.Struct("<cQqQ")
COMMAND_HEAD = struct.Struct("<cQqB")
HELLO_TIMEOUT_S = 2.0
FLAG_VALUES, STOP_VALUES = (0.0, 1.0), (-1.0, 0.0, 1.0, 2.0)  # what a state packet's last three fields may be
ADDRESS = re.compile(r"(?:udp://)?(?:127\.0\.0\.1|localhost):([0-9]{1,5})", re.IGNORECASE)
# the servo periods a run drives a robot at (a LeRobot robot's hz: 1 to 1000; a chunk's step: 1 ms to 1 s): a
# period of 1 ns sized the loop's cycle buffer at 89 GiB (a MemoryError traceback)
PERIOD_NS = (10**6, 10**9)


def parse_address(argument: str) -> tuple[str, int]:
    """``udp://127.0.0.1:PORT`` (loopback only) -> (host, port); nothing else in it (a path, query, fragment, user
    or whitespace was dropped without a word, and the run went to the port)."""
    match = ADDRESS.fullmatch(argument)
    port = int(match[1]) if match else 0
    if not 1 <= port <= 65535:
        raise ScenarioError(f"robot: sim-server address must be udp://127.0.0.1:PORT (loopback, port 1-65535, "
                            f"nothing else), got {argument!r}")
    return "127.0.0.1", port


class Layout:
    """Where each field sits in a state packet's float64 body, for ``dof`` joints and the measurements."""

    def __init__(self, dof: int, measurements: dict[str, int]):
        self.dof, self.measurements = dof, dict(measurements)
        self.size = 5 * dof + sum(self.measurements.values()) + 3

    def pack_state(self, seq: int, t_ns: int, cmd_seq: int, state: State, sent, measurements: dict,
                   cycle_done: bool, safety: SafetyInputs) -> bytes:
        body = np.concatenate([state.q, state.qd, state.effort, state.current, sent,
                               *[np.asarray(measurements[k], dtype=np.float64).ravel() for k in self.measurements],
                               [float(cycle_done), -1.0 if safety.stop is None else float(safety.stop),
                                float(safety.reduced_speed)]])
        return STATE_HEAD.pack(b"S", seq, t_ns, cmd_seq) + body.astype("<f8").tobytes()

    def unpack_state(self, packet: bytes):
        """A state packet of another length, or with flags that are not 0/1 or a stop that is not a category,
        raises ``robot_read_failed``: its fields cannot be told apart or read as what they are."""
        expected = STATE_HEAD.size + 8 * self.size
        if len(packet) != expected:
            raise RobotLinkError("robot_read_failed", f"sim-server state packet of {len(packet)} bytes, expected "
                                 f"{expected} ({self.size} values)")
        _, seq, t_ns, cmd_seq = STATE_HEAD.unpack_from(packet)
        body = np.frombuffer(packet, dtype="<f8", offset=STATE_HEAD.size)
        body = body.astype(np.float64)  # one private copy per packet; the fields below are views of it
        d = self.dof
        state = State(t_ns, body[0:d], body[d:2 * d], body[2 * d:3 * d], body[3 * d:4 * d])
        i, measurements = 5 * d, {}
        for name, n in self.measurements.items():
            measurements[name] = body[i:i + n]
            i += n
        cycle_done, stop, reduced_speed = body[i], body[i + 1], body[i + 2]
        if cycle_done not in FLAG_VALUES or stop not in STOP_VALUES or reduced_speed not in FLAG_VALUES:
            raise RobotLinkError("robot_read_failed", f"sim-server state packet with cycle_done {cycle_done}, "
                                 f"safety_stop {stop}, reduced_speed {reduced_speed}; expected 0 or 1, -1 (none) or "
                                 "0-2, 0 or 1")
        stop = int(stop)
        return seq, state, measurements, bool(cycle_done), _safety(None if stop < 0 else stop, bool(reduced_speed))


@functools.lru_cache(maxsize=16)
def _safety(stop: int | None, reduced_speed: bool) -> SafetyInputs:
    """The (frozen) safety inputs of a state packet; the few distinct values are shared, not rebuilt per tick."""
    return SafetyInputs(stop, reduced_speed)


def pack_command(seq: int, t_ns: int, power: bool, setpoint: np.ndarray) -> bytes:
    return COMMAND_HEAD.pack(b"C", seq, t_ns, int(power)) + np.asarray(setpoint, dtype="<f8").tobytes()


def command_size(dof: int) -> int:
    """The length of a command packet for ``dof`` joints [bytes]."""
    return COMMAND_HEAD.size + 8 * dof


def unpack_command(packet: bytes, dof: int):
    """(seq, t_ns, power, setpoint) of a command packet; None for a packet of another length."""
    if len(packet) != command_size(dof):
        return None
    _, seq, t_ns, power = COMMAND_HEAD.unpack_from(packet)
    return seq, t_ns, bool(power), np.frombuffer(packet, dtype="<f8", offset=COMMAND_HEAD.size)


class SimServerRobot:
    """A Robot whose state and commands travel over UDP to ``cellguard sim-server``.

    ``read`` returns the newest state packet (never blocks longer than ``read_timeout_s``);
    ``dropped`` counts sequence gaps; a refused port (the server gone) or silence longer than the
    timeout raises ``RobotLinkError``. ``write`` refuses a non-finite setpoint before packing it.
    """

    def __init__(self, address: tuple[str, int], read_timeout_s: float = 0.05, cell: str | None = None):
        """``cell``: the cell the scenario names, which the server must serve (None: whichever it serves)."""
        self.address, self.read_timeout_ns = address, round(read_timeout_s * 1e9)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(address)
        try:
            self._connect(cell)
        except BaseException:  # said hello: say goodbye, or the server holds the session for this dead client
            self.close()
            raise

    def _connect(self, cell: str | None) -> None:
        self.meta = self._hello()
        if cell is not None and self.meta["cell"] != cell:
            raise self._other_cell(cell)
        from cellguard.robot.registry import make_cell

        self._model = make_cell(self.meta["cell"], seed=self.meta["seed"])  # kinematics and profile only
        self.name, self.profile, self.dt_ns = self._model.name, self._model.profile, self.meta["dt_ns"]
        self.q_home = self._home(self.meta.get("q_home"))
        self.tool_point = self._model.tool_point if hasattr(self._model, "tool_point") else None
        self.workspace_box = getattr(self._model, "workspace_box", None)
        self.layout = Layout(self.profile.dof, self.meta["measurements"])
        self.dropped = 0
        self._seq = self._cmd_seq = 0
        self._power = True
        self._latest = None
        self._last_packet_ns = time.monotonic_ns()
        self.sock.setblocking(False)
        self._wait_first()
        self._setpoint = self._latest[0].q.copy()  # the last setpoint sent (before any: the measured pose)

    # -- connection -------------------------------------------------------------------------
    def _hello(self) -> dict:
        self.sock.settimeout(HELLO_TIMEOUT_S)
        try:
            self.sock.send(b"H")
            while True:
                packet = self.sock.recv(65536)
                if packet[:1] == b"M":
                    return self._metadata(packet[1:])
                if packet[:1] == b"B":
                    raise self._busy(packet[1:])
        except (TimeoutError, ConnectionRefusedError) as exc:
            raise RobotLinkError("robot_server_gone", f"sim-server at {self.address[0]}:{self.address[1]} does not "
                                 f"answer ({type(exc).__name__}); start it with: cellguard sim-server CELL "
                                 f"--port {self.address[1]}", lost=True) from None

    def _busy(self, text: bytes) -> RobotLinkError:
        """The server serves a live client: taking over would leave that run driving a robot that no longer
        listens to it."""
        try:
            busy = json.loads(text)
            client, silent, live = str(busy["client"])[:60], float(busy["silent_ms"]), float(busy["live_ms"])
        except (ValueError, TypeError, KeyError, RecursionError):  # RecursionError: JSON nested thousands deep
            client, silent, live = "another client", float("nan"), float("nan")
        return RobotLinkError("robot_read_failed", f"sim-server at {self.address[0]}:{self.address[1]} is serving "
                              f"{client} (heard {silent:.0f} ms ago); it takes a new client once its client has "
                              f"been silent for {live * 1e-3:.0f} s", lost=True)

    def _other_cell(self, cell: str) -> ScenarioError:
        """The server serves another cell than the scenario names: the run drove and guarded the served robot
        while its summary named the scenario's cell, registered or not."""
        served = repr(self.meta["cell"])[:60]
        return ScenarioError(f"cell: the scenario names {cell!r} but the sim-server at {self.address[0]}:"
                             f"{self.address[1]} serves {served}; name the served cell, or serve the scenario's")

    def _metadata(self, text: bytes) -> dict:
        """The hello's answer, each field the bridge reads checked before it is used (a period of 0 divided by
        zero later, a missing cell raised KeyError): metadata of another shape is one line naming the field."""
        try:
            meta = json.loads(text)
        except (ValueError, RecursionError):  # not JSON, not UTF-8, or nested thousands deep
            meta = None
        if not isinstance(meta, dict):
            raise self._bad_metadata("metadata", "a JSON object", repr(text[:60]))
        checks = {"cell": ("a cell name", lambda v: isinstance(v, str)),
                  "seed": ("an integer 0 to 2^32-1", lambda v: _is_int(v, 0, 2**32 - 1)),
                  "dt_ns": ("the servo period, an integer 10^6 to 10^9 [ns] (1 kHz to 1 Hz)",
                            lambda v: _is_int(v, *PERIOD_NS)),
                  "measurements": ("{name: size}, each size an integer 0 to 65536", lambda v: isinstance(v, dict)
                                   and all(isinstance(k, str) and _is_int(n, 0, 2**16) for k, n in v.items()))}
        for field, (expected, valid) in checks.items():
            if not valid(meta.get(field)):
                raise self._bad_metadata(field, expected, repr(meta[field])[:60] if field in meta else "nothing")
        return meta

    def _home(self, value) -> np.ndarray:
        """The metadata's home pose: one finite position per joint (a short one crashed the retreat at the end
        of the run, a NaN one skipped it), each within its joint's limits (one beyond was clamped without a word:
        the retreat went elsewhere)."""
        try:
            home = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            home = np.full(0, np.nan)
        if home.shape != (self.profile.dof,) or not np.isfinite(home).all():
            raise self._bad_metadata("q_home", f"{self.profile.dof} finite joint positions", repr(value)[:60])
        p = self.profile
        j = p.first_outside(home)
        if j is not None:
            raise self._bad_metadata("q_home", f"within the joint limits, {p.joint_names[j]} within "
                                     f"[{float(p.q_min[j])!r}, {float(p.q_max[j])!r}]", repr(float(home[j])))
        return home

    def _bad_metadata(self, field: str, expected: str, got: str) -> RobotLinkError:
        return RobotLinkError("robot_read_failed", f"sim-server at {self.address[0]}:{self.address[1]} sent bad "
                              f"metadata: {field} must be {expected}, got {got}")

    def _wait_first(self) -> None:
        deadline = time.monotonic_ns() + round(HELLO_TIMEOUT_S * 1e9)
        while self._latest is None:
            self._drain()
            if time.monotonic_ns() > deadline:
                raise RobotLinkError("robot_read_timeout", "sim-server sent no state after hello", lost=True)
            time.sleep(0.001)

    def _drain(self) -> None:
        """Take every packet waiting; keep the newest state; count sequence gaps as lost packets."""
        while True:
            try:
                packet = self.sock.recv(65536)
            except BlockingIOError:
                return
            except ConnectionRefusedError:
                raise RobotLinkError("robot_server_gone", "sim-server refused the connection (process gone)",
                                     lost=True) from None
            if packet[:1] != b"S":
                continue
            seq, *rest = self.layout.unpack_state(packet)
            if self._latest is not None:
                if seq <= self._seq:
                    continue  # reordered or duplicate: older than what we have
                self.dropped += seq - self._seq - 1
            self._seq, self._latest = seq, rest
            self._last_packet_ns = time.monotonic_ns()

    def resync(self) -> None:
        """Before the clock starts: drop what queued up while the loop was busy (a slow policy warm-up
        fills the socket buffer with old states and the kernel drops the rest) and wait for a fresh state."""
        deadline = time.monotonic_ns() + round(HELLO_TIMEOUT_S * 1e9)
        self._drain()
        while time.monotonic_ns() - self._latest[0].t_ns > 2 * self.dt_ns and time.monotonic_ns() < deadline:
            time.sleep(self.dt_ns * 0.5e-9)
            self._drain()
        self.dropped = 0

    # -- Robot ----------------------------------------------------------------------------------
    def read(self) -> State:
        self._drain()
        silent = time.monotonic_ns() - self._last_packet_ns
        if silent > self.read_timeout_ns:
            raise RobotLinkError("robot_read_timeout", f"no state from the sim-server for {silent * 1e-6:.0f} ms",
                                 lost=silent > 4 * self.read_timeout_ns)
        return self._latest[0]

    def observe(self) -> Observation:
        state, measurements = self._latest[0], self._latest[1]
        return Observation(state.t_ns, state.q, state.qd, measurements)

    def write(self, setpoint: np.ndarray) -> np.ndarray:
        setpoint = np.asarray(setpoint, dtype=np.float64)
        if setpoint.shape != (self.profile.dof,) or not np.isfinite(setpoint).all():
            raise RobotLinkError("robot_write_failed", f"setpoint refused before the wire: shape {setpoint.shape}, "
                                 "every value must be finite")
        self._cmd_seq += 1
        try:
            self.sock.send(pack_command(self._cmd_seq, time.monotonic_ns(), self._power, setpoint))
        except ConnectionRefusedError:
            raise RobotLinkError("robot_server_gone", "sim-server refused the command (process gone)",
                                 lost=True) from None
        except OSError as exc:
            raise RobotLinkError("robot_write_failed", f"send failed: {exc.strerror}") from None
        self._setpoint = sent = setpoint.copy()  # what a power-off goes out with
        return sent

    def safety(self) -> SafetyInputs:
        return self._latest[3]

    digital_inputs = ("cycle_done",)  # what a state packet carries

    def digital_input(self, name: str) -> bool:
        if name not in self.digital_inputs:
            raise RobotLinkError("robot_read_failed", f"sim-server has no digital input {name!r}; it has: cycle_done")
        return self._latest[2]

    def set_power(self, on: bool) -> None:
        """Off goes out at once, in a command with the last setpoint (the server takes a power-off with any): a loop
        that writes nothing more after it (a lost link) left the robot powered. On goes out with the next write."""
        self._power = bool(on)
        if not on:
            self.write(self._setpoint)

    def context(self) -> dict:
        return {**self._model.context(), "robot": f"sim-server:udp://{self.address[0]}:{self.address[1]}"}

    def counters(self) -> dict:
        """The server's counters (commands received, packets refused by reason) [blocking, for tests]."""
        self.sock.setblocking(True)
        self.sock.settimeout(1.0)
        try:
            self.sock.send(b"?")
            while True:
                packet = self.sock.recv(65536)
                if packet[:1] == b"R":
                    return json.loads(packet[1:])
        finally:
            self.sock.setblocking(False)

    def close(self) -> None:
        """Say goodbye (``G``): the server takes the next client at once, not after a second of silence."""
        with contextlib.suppress(OSError):
            self.sock.send(b"G")
        self.sock.close()


def _is_int(value, low: int, high: int) -> bool:
    """An integer in ``low..high`` (JSON's true and false are not numbers)."""
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def connect_sim_server(spec, scenario) -> SimServerRobot:
    return SimServerRobot(parse_address(spec.argument), read_timeout_s=scenario.realtime.read_timeout_s,
                          cell=scenario.cell)
