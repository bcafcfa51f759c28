"""``cellguard sim-server``: a simulated cell served as a robot, stepping on wall time in its own process.

One servo period per tick, paced by ``WallClock``: take the newest command (a non-finite one is
counted and never applied), step the physics, and send the client one state packet stamped
with the monotonic clock. A period is whole physics steps: a ``rate_hz`` they cannot serve within 1 % is refused,
and the start line says the rate served. The cell runs its own task (``OwnTask``): when a cycle is over the
next part arrives at once and the digital input ``cycle_done`` pulses.

A hello starts a session: its sender is the client, and the command sequence starts again.
While the client is live (heard within ``CLIENT_LIVE_NS``; within ``STARTING_LIVE_NS`` before
its first command, while its run loads and warms up its policy), another peer's hello is refused
with a ``B`` packet naming the client: a second run took over the robot from a run still
driving it, which then read a silent server. A client's goodbye (``G``) ends its session at
once; a client silent that long has gone (a crashed run restarts on a new port) and the next
hello takes over. On Linux a client whose process has died is gone at once: the kernel reports its
closed port (ICMP port unreachable, read from the socket's error queue with the address it was
for), so a run that crashed during its warm-up does not hold the robot for 30 s. A packet the server does not
act on (a command from another peer, an older or non-finite one, a setpoint outside a joint's position range,
a malformed packet) is counted by reason and said on stderr, the first of each reason and then at most once
a second; a new client and a goodbye are said the same way. Peers other than the client get at most
``FOREIGN_REPLIES_PER_S`` answers a second (a refused hello's ``B``, a counter query's ``R``): a flood of
them delayed the client's state packets by 46 ms.

For tests of the robot link, the server can misbehave on purpose: ``delay_ms`` holds every
state packet back, ``drop_every`` loses every n-th one. These are transport faults of the
simulated robot, not cell faults.
"""

from __future__ import annotations

import json
import math
import socket
import sys
import time
from collections import deque

import numpy as np

from cellguard.errors import ConfigError
from cellguard.robot.bridges.sim_server import PERIOD_NS, Layout, command_size, unpack_command
from cellguard.robot.own_task import OwnTask
from cellguard.robot.registry import make_cell
from cellguard.runtime.clock import WallClock

NOTE_EVERY_NS = 1_000_000_000  # a refusal of one reason is said on stderr at most this often
CLIENT_LIVE_NS = 1_000_000_000  # a client heard within this is live; a hello from another peer is refused
STARTING_LIVE_NS = 30_000_000_000  # the same before its first command (a policy's warm-up sends nothing)
FOREIGN_REPLIES_PER_S = 20  # answers a second to peers other than the client (refused hellos, counter queries)
RATE_TOLERANCE = 0.01  # --rate-hz is served if whole physics steps per period come this close (333 Hz: 3 ms)
IP_RECVERR = 11  # Linux: queue ICMP errors with the address they were for (the socket module has no name for it)


class SimServer:
    """The server's state: the cell, its socket, the client, the counters."""

    def __init__(self, cell_name: str, port: int, seed: int = 0, delay_ms: float = 0.0, drop_every: int = 0,
                 rate_hz: float | None = None):
        self.cell = make_cell(cell_name, seed=seed)
        cell = self.cell
        self.substeps = 1 if rate_hz is None else served_substeps(rate_hz, cell.dt_ns)
        self.dt_ns = self.substeps * cell.dt_ns
        if not PERIOD_NS[0] <= self.dt_ns <= PERIOD_NS[1]:  # every client would refuse it, after the start
            raise ConfigError(f"{cell_name}: a servo period of {self.dt_ns * 1e-6:g} ms is not one a run drives "
                              f"(1 ms to 1 s): serve it with --rate-hz, 50 to 1000 Hz")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self._errors_queued = sys.platform.startswith("linux") and hasattr(socket, "MSG_ERRQUEUE")
        if self._errors_queued:
            self.sock.setsockopt(socket.IPPROTO_IP, IP_RECVERR, 1)
        self.port = self.sock.getsockname()[1]
        self.delay_ns, self.drop_every = round(delay_ms * 1e6), int(drop_every)
        obs = cell.observe()
        self.meta = {"cell": cell.name, "seed": seed, "dt_ns": self.dt_ns, "joints": list(cell.profile.joint_names),
                     "measurements": {k: int(np.asarray(v).size) for k, v in obs.measurements.items()},
                     "q_home": np.asarray(getattr(cell, "q_home", cell.read().q)).tolist(), "inputs": ["cycle_done"]}
        self.layout = Layout(cell.profile.dof, self.meta["measurements"])
        self.client, self._heard_ns = None, 0  # the client, and when it last sent a packet [ns]
        self.q_range = (cell.profile.q_min, cell.profile.q_max)  # a real controller refuses a target beyond these
        self.counters = {"commands": 0, "nonfinite_commands": 0, "out_of_range_commands": 0, "stale_commands": 0,
                         "foreign_commands": 0, "refused_hellos": 0, "malformed_packets": 0, "states_sent": 0,
                         "states_dropped": 0, "cycles": 0, "sessions": 0}
        self._power, self._cmd_seq, self._seq = True, 0, 0
        self._noted: dict[str, int] = {}  # when each reason was last said on stderr [ns]
        self._foreign_replies: deque = deque()  # when the last answers to other peers went out [ns]
        self._delayed: deque = deque()
        self.task = OwnTask(cell)

    def tick(self) -> None:
        cell, now = self.cell, time.monotonic_ns()
        self._receive()
        if self.task.poll(now):
            self.counters["cycles"] += 1
        for _ in range(self.substeps):
            cell.step()
        if self.client is None:
            return
        state = cell.read()._replace(t_ns=time.monotonic_ns())
        obs = cell.observe()
        self._seq += 1
        packet = self.layout.pack_state(self._seq, state.t_ns, self._cmd_seq, state, cell.data.ctrl[cell.drives.act],
                                        obs.measurements, self.task.cycle_done(now), cell.safety())
        if self.drop_every and self._seq % self.drop_every == 0:
            self.counters["states_dropped"] += 1
        else:
            self._delayed.append((now + self.delay_ns, packet))
        while self._delayed and self._delayed[0][0] <= now:
            self._send(self._delayed.popleft()[1], self.client, state=True)

    def _receive(self) -> None:
        while True:
            try:
                packet, addr = self.sock.recvfrom(65536)
            except BlockingIOError:
                return
            except ConnectionRefusedError:  # a port we sent to is closed: which one is in the error queue
                if not self._errors_queued:
                    return
                self._closed_ports()
                continue
            kind = packet[:1]
            if addr == self.client:
                self._heard_ns = time.monotonic_ns()
            if kind == b"H":
                self._hello(addr)
            elif kind == b"?":
                self._reply(b"R" + json.dumps(self.counters).encode(), addr)
            elif kind == b"C":
                self._command(packet, addr)
            elif kind == b"G":
                self._goodbye(addr)
            else:
                self._refuse("malformed_packets", f"dropped a packet of {len(packet)} bytes from {_peer(addr)}: "
                                                  f"unknown kind {kind!r} (H, C, G or ?)")

    def _hello(self, addr) -> None:
        """A new session: the sender is the client, and its commands count from 1 again (a second run's were all
        older than the first run's last one, and ignored). Refused while another client is live."""
        silent_ns = time.monotonic_ns() - self._heard_ns
        live_ns = CLIENT_LIVE_NS if self._cmd_seq else STARTING_LIVE_NS
        if self.client is not None and addr != self.client and silent_ns < live_ns:
            busy = {"client": _peer(self.client), "silent_ms": round(silent_ns * 1e-6), "live_ms": live_ns // 10**6}
            self._refuse("refused_hellos", f"refused a hello from {_peer(addr)}: client {busy['client']} is live "
                                           f"(heard {busy['silent_ms']} ms ago)")
            self._reply(b"B" + json.dumps(busy).encode(), addr)
            return
        if addr != self.client:
            before = "" if self.client is None else f"; commands from {_peer(self.client)} are refused from now on"
            self.counters["sessions"] += 1
            self._note("sessions", f"client {_peer(addr)} said hello{before}")
            self.task.new_session()
        self.client, self._cmd_seq, self._heard_ns = addr, 0, time.monotonic_ns()
        self._delayed.clear()
        self._send(b"M" + json.dumps(self.meta).encode(), addr)

    def _goodbye(self, addr, why: str = "said goodbye") -> None:
        """The client closed: the next hello is taken at once, and no state is sent to a closed socket."""
        if addr == self.client:
            self.client = None
            self._delayed.clear()
            self._note("ended_sessions", f"client {_peer(addr)} {why}")

    def _closed_ports(self) -> None:
        """Read the error queue: a packet to the client came back port-unreachable, so its process has gone."""
        while True:
            try:
                _, _, _, addr = self.sock.recvmsg(1, 512, socket.MSG_ERRQUEUE)
            except OSError:  # empty (BlockingIOError), or nothing more to read
                return
            self._goodbye(addr, why="is gone (its port is closed)")

    def _command(self, packet: bytes, addr) -> None:
        """Apply a command of the client's that is newer than the one in force; refuse any other (a peer that never
        said hello moved the robot, and its seq 2^64-1 locked every client out)."""
        if addr != self.client:
            self._refuse("foreign_commands", f"refused a command from {_peer(addr)}: not the client (say hello first)")
            return
        dof = self.cell.profile.dof
        parsed = unpack_command(packet, dof)
        if parsed is None:
            self._refuse("malformed_packets", f"dropped a command of {len(packet)} bytes, expected "
                                              f"{command_size(dof)} ({dof} joints)")
            return
        seq, _, power, setpoint = parsed
        self.counters["commands"] += 1
        refused = self._refused_setpoint(seq, setpoint)
        if seq <= self._cmd_seq:
            if not refused:
                self._refuse("stale_commands", f"ignored command {seq}: not newer than command {self._cmd_seq} in "
                                               f"force")
            return
        if refused:
            if not power and self._power:  # a power-off is a stop: taken whatever setpoint came with it
                self._power = False
                self.cell.set_power(False)
            return
        self._cmd_seq = seq
        if power != self._power:
            self._power = power
            self.cell.set_power(power)
        self.cell.write(setpoint)

    def _refused_setpoint(self, seq: int, setpoint: np.ndarray) -> bool:
        """Count and say a setpoint the drives must not take (not finite, or past a joint's position limit, as a
        controller refuses a target beyond its range); True if so."""
        if not np.isfinite(setpoint).all():
            self._refuse("nonfinite_commands", f"refused command {seq}: a setpoint value is not finite")
            return True
        lo, hi = self.q_range
        outside = np.flatnonzero((setpoint < lo) | (setpoint > hi))
        if not outside.size:
            return False
        j = int(outside[0])
        side, limit = ("upper", hi[j]) if setpoint[j] > hi[j] else ("lower", lo[j])
        self._refuse("out_of_range_commands", f"refused command {seq}: {self.cell.profile.joint_names[j]} setpoint "
                                              f"{setpoint[j]:.9g} is {abs(setpoint[j] - limit):.3g} past its {side} "
                                              f"limit {limit:.9g}")
        return True

    def _refuse(self, reason: str, why: str) -> None:
        """Count a packet not acted on under ``reason`` and say ``why``."""
        self.counters[reason] += 1
        self._note(reason, f"{why} ({reason}: {self.counters[reason]})")

    def _note(self, reason: str, line: str) -> None:
        """Say ``line`` on stderr the first time and then at most once a second per ``reason`` (a flood of hellos,
        goodbyes or refusals neither fills the log nor stalls the tick)."""
        now, last = time.monotonic_ns(), self._noted.get(reason)
        if last is None or now - last >= NOTE_EVERY_NS:
            self._noted[reason] = now
            sys.stderr.write(f"sim-server: {line}\n")

    def _reply(self, packet: bytes, addr) -> None:
        """Answer a peer: the client always, others at most ``FOREIGN_REPLIES_PER_S`` times a second in all."""
        if addr != self.client:
            now, sent = time.monotonic_ns(), self._foreign_replies
            while sent and now - sent[0] >= 1_000_000_000:
                sent.popleft()
            if len(sent) >= FOREIGN_REPLIES_PER_S:
                return
            sent.append(now)
        self._send(packet, addr)

    def _send(self, packet: bytes, addr, state: bool = False) -> None:
        """Send one packet; a peer that went away is no error (it says hello again when it comes back)."""
        for _ in range(2):
            try:
                self.sock.sendto(packet, addr)
            except ConnectionRefusedError:  # said of an earlier packet, and this one not sent: to which port?
                if not self._errors_queued:
                    return
                self._closed_ports()
                if state and self.client is None:
                    return  # the refused port was the client's
                continue
            except OSError:
                return
            if state:
                self.counters["states_sent"] += 1
            return


def _peer(addr) -> str:
    return f"{addr[0]}:{addr[1]}"


def served_substeps(rate_hz: float, step_ns: int) -> int:
    """Physics steps per servo period for ``rate_hz``: a period is whole steps of the cell's physics, so a rate
    that none serves within ``RATE_TOLERANCE`` is refused, naming the nearest that are (400 Hz was served at
    500 Hz and 60 Hz at 58.8 Hz without a word, and the client took the served period as the robot's)."""
    exact = 1e9 / rate_hz / step_ns
    steps = max(1, round(exact))
    if abs(_rate_hz(steps, step_ns) - rate_hz) <= RATE_TOLERANCE * rate_hz:
        return steps
    nearby = sorted({_rate_hz(max(1, n), step_ns) for n in (math.floor(exact), math.ceil(exact))})
    raise ConfigError(f"--rate-hz: {rate_hz:g} Hz is not served: a servo period is a whole number of the cell's "
                      f"{step_ns * 1e-6:g} ms physics steps; nearest rates served: "
                      f"{' and '.join(f'{r:.4g}' for r in nearby)} Hz")


def _rate_hz(steps: int, step_ns: int) -> float:
    return 1e9 / (steps * step_ns)


def serve(cell_name: str, port: int, seed: int = 0, delay_ms: float = 0.0, drop_every: int = 0,
          duration_s: float | None = None, rate_hz: float | None = None) -> None:
    """Serve ``cell_name`` on udp://127.0.0.1:``port`` until killed (or for ``duration_s``)."""
    server = SimServer(cell_name, port, seed, delay_ms, drop_every, rate_hz)
    clock = WallClock(server.dt_ns, step=server.tick)
    sys.stdout.write(f"sim-server {cell_name} on udp://127.0.0.1:{server.port} at "
                     f"{1e9 / server.dt_ns:.4g} Hz ({server.dt_ns * 1e-6:g} ms period)\n")
    sys.stdout.flush()
    end = None if duration_s is None else time.monotonic_ns() + round(duration_s * 1e9)
    clock.start()
    with clock.ticking():  # the served robot's controller: a real-time thread where permitted
        while end is None or time.monotonic_ns() < end:
            clock.advance()
