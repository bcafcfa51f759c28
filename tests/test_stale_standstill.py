"""A category 1 stop reads standstill only from a fresh state: a state the link flagged stale (or the last good one
standing in for a failed read) never completes it. The probe: a sim-server stopped (SIGSTOP) mid-cycle, its last
state read stale, and power went "category 1 stop complete" 54 ms later on the frozen state's 0.0015 rad/s.

The arm cell behind a bus that freezes or fails for a stretch, read through the real ``RobotLink`` into the real
``Envelope``; then a real ``cellguard sim-server`` process stopped and continued.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest
from sim_server_util import scenario, server_counters, start_server, sway_file

from cellguard.control.envelope import SETTLE_MIN_NS, STANDSTILL, Envelope, StaleState, stopping_time_ns
from cellguard.robot.protocol import RobotLinkError, SafetyInputs
from cellguard.robot.registry import make_cell
from cellguard.robot.state import State
from cellguard.runtime import Run, run_scenario
from cellguard.runtime.link import RobotLink
from cellguard.scenario import parse_scenario

MS = 1_000_000
STALE_NS = 20 * MS
BAD_FROM = 300  # the bus goes bad on this read, the arm settled (its last state reads still), as it starts to move


class _Bus:
    """The arm cell behind a bus that, on reads ``bad``, gives its last state again (``how="frozen"``: a stale
    stamp) or raises a read time-out (``how="failing"``)."""

    def __init__(self, bad: range, how: str):
        self.cell, self.bad, self.how, self.reads, self.last = make_cell("arm-pick-place"), bad, how, 0, None

    def read(self):
        k, self.reads = self.reads, self.reads + 1
        if k in self.bad:
            if self.how == "failing":
                raise RobotLinkError("robot_read_timeout", "no state from the bus")
            return self.last
        self.last = self.cell.read()
        return self.last

    def write(self, q):
        return self.cell.write(q)


def _reference(q0: np.ndarray, k: int) -> np.ndarray:
    """Joint 0 held, then from ``BAD_FROM`` on swings: the arm moves while a frozen state still reads it at rest."""
    q = q0.copy()
    q[0] += 0.3 * (1.0 - np.cos(3.0 * max(k - BAD_FROM, 0) * 1e-3))
    return q


def _run(bad: range, how: str, ticks: int):
    """The runner's tick path (read, guard, write, step), the link's stop asked of the envelope; per tick: whether
    the state handed over was stale, and power; and every event."""
    bus = _Bus(bad, how)
    cell, events, log = bus.cell, [], []
    q0 = cell.read().q
    link = RobotLink(bus, events, stop_category=1, stale_ns=STALE_NS)
    envelope = Envelope(cell.profile, q0, MS)
    for k in range(ticks):
        t = cell.t_ns
        state = link.read(t)
        safety = SafetyInputs() if link.stop is None else SafetyInputs(stop=link.stop)
        setpoint, new = envelope.apply(t, _reference(q0, k), state, safety)
        events += new
        if not envelope.power:
            cell.set_power(False)
        link.write(t, setpoint)
        cell.step()
        log.append((isinstance(state, StaleState), envelope.power))
    return log, events


def _power_removed(log, events):
    off = next(k for k, (_, power) in enumerate(log) if not power)
    return off, next(e for e in events if e.kind == "power_removed")


@pytest.mark.parametrize("how, kind", [("frozen", "robot_state_stale"), ("failing", "robot_read_timeout")])
def test_a_category_1_stop_waits_for_a_fresh_state_to_read_standstill_from(how, kind):
    log, events = _run(range(BAD_FROM, BAD_FROM + 400), how, ticks=BAD_FROM + 700)
    fault = next(e for e in events if e.kind == kind)
    assert fault.category == 1 and fault.t_ns <= (BAD_FROM + 25) * MS  # asked while bad
    off, removed = _power_removed(log, events)
    assert off >= BAD_FROM + 400 and not log[off][0]  # power stayed on through every stale state
    assert all(stale for stale, _ in log[BAD_FROM + 25:BAD_FROM + 400])  # bad reads past the limit: stale
    assert removed.category == 1 and removed.reason.startswith("category 1 stop complete")
    assert "standstill read from a fresh state after" in removed.reason and "ms of stale ones" in removed.reason
    assert removed.asked < STANDSTILL and removed.joint is not None


def test_only_stale_states_remove_power_at_the_settle_time_saying_there_was_no_fresh_one():
    log, events = _run(range(BAD_FROM, 10_000), "frozen", ticks=BAD_FROM + 1600)
    off, removed = _power_removed(log, events)
    stop = next(e for e in events if e.kind == "protective_stop")
    settle = max(stopping_time_ns(make_cell("arm-pick-place").profile), SETTLE_MIN_NS)
    assert off * MS - stop.t_ns >= settle  # the setpoint rested after the stop began: at least the settle time
    assert "no fresh state to read standstill from" in removed.reason and "power removed anyway" in removed.reason
    assert removed.joint is None and removed.asked is None  # no speed was measured to cite


def test_a_fresh_state_after_a_stale_one_is_handed_over_as_it_is():
    log, _ = _run(range(BAD_FROM, BAD_FROM + 50), "frozen", ticks=BAD_FROM + 60)
    assert not any(stale for stale, _ in log[:BAD_FROM + 20])  # a stamp up to 20 ms old is fresh
    assert log[BAD_FROM + 30][0] and not any(stale for stale, _ in log[BAD_FROM + 51:])


def test_a_sim_server_stopped_mid_cycle_keeps_power_until_its_states_are_fresh_again(tmp_path):
    """The probe, on a real server process: SIGSTOP mid-cycle for 0.7 s, then SIGCONT. The stale state starts a
    category 1 stop; its power goes only on a fresh state after the server continued (or, were none to come, the
    link's category 0 once lost), never on the frozen one."""
    proc, port = start_server()
    continued = []
    try:
        def pause():  # mid-cycle: once the loop has commanded for 0.5 s
            while server_counters(port).get("commands", 0) < 500:
                time.sleep(0.01)
            os.kill(proc.pid, signal.SIGSTOP)
            time.sleep(0.7)
            continued.append(time.monotonic_ns())
            os.kill(proc.pid, signal.SIGCONT)

        threading.Thread(target=pause, daemon=True).start()
        spec = scenario(port, sway_file(tmp_path / "sway.npz"), stale_s=0.25, read_timeout_s=0.5, stop_category=1)
        run = Run(parse_scenario({**spec, "cycle": {"source": "time", "seconds": 4.0}}))
        summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    finally:
        os.kill(proc.pid, signal.SIGCONT)
        proc.kill()
        proc.wait()
    events = summary["events"]
    stale = next(e for e in events if e["kind"] == "robot_state_stale")
    removed = next(e for e in events if e["kind"] == "power_removed")
    assert stale["category"] == 1 and stale["t_ns"] <= removed["t_ns"], events
    assert continued and removed["t_ns"] >= continued[0], events  # not on the frozen state
    # read from a fresh state (a stale one never completes it; the first fresh ones may still move)
    assert removed["category"] == 1 and removed["reason"].startswith("category 1 stop complete"), events


def _envelope_power_off(states, stop: int = 1):
    """Feed the real envelope ``states(k, q0)`` at rest under a category ``stop`` stop; the tick power went and its
    event."""
    cell = make_cell("arm-pick-place")
    q0 = cell.read().q
    envelope = Envelope(cell.profile, q0, MS)
    for k in range(3000):
        _, new = envelope.apply(k * MS, q0, states(k, q0), SafetyInputs(stop=stop))
        removed = [e for e in new if e.kind == "power_removed"]
        if removed:
            return k, removed[0]
    raise AssertionError("power never removed")


def test_a_state_stamped_ahead_of_the_loop_reads_standstill_at_once():
    """A bridge that stamps after its 25 ms bus read: every state 25 ms 'ahead' (limit 20 ms). A fault, but its data
    is fresh: the arm at rest stops at once, not after the settle time."""
    cell = make_cell("arm-pick-place")
    zero = np.zeros(cell.profile.dof)
    events = []

    class Bus:
        t = 0

        def read(self):
            return cell.read()._replace(t_ns=self.t + 25 * MS, qd=zero)

        def write(self, q):
            return q

    bus = Bus()
    link = RobotLink(bus, events, stop_category=1, stale_ns=STALE_NS)

    def states(k, _):
        bus.t = k * MS
        return link.read(k * MS)

    k, removed = _envelope_power_off(states)
    assert k == 0 and removed.reason.startswith("category 1 stop complete"), removed.reason
    assert any(e.kind == "robot_state_stale" and "ahead" in e.reason for e in events)


def test_fresh_states_end_the_stale_stretch_the_power_off_event_names():
    """Stale for 5 ms, then fresh ones that still move for 500 ms: standstill read then is no 'after 505 ms of stale
    ones'."""
    zero = np.zeros(make_cell("arm-pick-place").profile.dof)

    def states(k, q0):
        qd = zero.copy()
        qd[0] = 0.2 if 5 <= k < 505 else 0.0
        state = StaleState(k * MS, q0, qd, zero, zero)
        return state if k < 5 else State(*state)

    k, removed = _envelope_power_off(states)
    assert k == 505 and removed.reason.startswith("category 1 stop complete")
    assert "stale ones" not in removed.reason, removed.reason


class _FailingFrom(Run):
    """The arm cell whose reads time out from ``fail_from`` s on; SIGTERM ``signal_at`` s in (None: none)."""

    def __init__(self, spec: dict, fail_from: float, fail_to: float, signal_at: float | None = None):
        super().__init__(parse_scenario(spec))
        read, self.signalled = self.link.robot.read, False

        def failing():
            t = self.cell.t_ns * 1e-9
            if signal_at is not None and t >= signal_at and not self.signalled:
                self.signalled = True
                signal.raise_signal(signal.SIGTERM)
            if fail_from <= t < fail_to:
                raise RobotLinkError("robot_read_timeout", "no state from the bus")
            return read()

        self.link.robot.read = failing


ONE_CYCLE = {"cell": "arm-pick-place", "seed": 3, "policy": "scripted", "acceptance_cycles": 1, "production_cycles": 0}


def test_an_operator_signal_during_a_link_category_1_stop_leaves_the_run_with_power_off(tmp_path):
    """The review's case: a read time-out 1.25 s in (category 1), SIGTERM 10 ms later, reads back at 1.45 s. The
    operator's standstill check ended the cycle on the first fresh state, before the guard's tick; the retreat is not
    played after a link fault: power stayed on."""
    run = _FailingFrom(ONE_CYCLE, 1.25, 1.45, signal_at=1.26)
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    kinds = [e["kind"] for e in summary["events"]]
    assert "operator_stop" in kinds and "power_removed" in kinds, kinds
    assert not run.guard.power
    assert summary["stopped"].startswith("robot link")  # the stop in force ended the cycle, not the operator's


def test_a_cycle_that_ends_during_a_category_1_stop_removes_power(tmp_path):
    """The cycle's source ends it 13 ms after a read time-out asked a category 1 stop, the arm still moving; no
    fresh state comes again. The retreat is not played after a link fault: power stayed on for good."""
    run = _FailingFrom(ONE_CYCLE, 4.43, 1e9)
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    removed = [e for e in summary["events"] if e["kind"] == "power_removed"]
    assert not run.guard.power and len(removed) == 1, summary["events"]
    assert removed[0]["category"] == 1 and "no fresh state to read standstill from" in removed[0]["reason"]
    assert summary["stopped"].startswith("robot link")
