"""Cycle sources: where one cycle of the loop ends, chosen by the scenario's ``cycle.source``.

A source has ``begin(index, t_ns)``, ``finished(state) -> bool`` (once per tick) and
``end(t_ns, stopped) -> dict`` (the cycle's outcome: ``success`` plus measured values, SI;
``stopped``: the cell was stopped during the cycle). The simulated cell's task is one source and
judges the part itself; on hardware a digital input (a PLC's part-done signal), a return to the
home pose, the policy's own episode end or a fixed episode time end a cycle, and a cycle in which
the cell was stopped is no success (a fixed time ran out on a robot that never moved). On a
simulated cell such a source only says when the cycle ends: the cell still presents each part and
judges it (without, the part stayed where the first cycle left it and every cycle read success).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellguard.errors import ScenarioError

LEFT_HOME = 5.0  # a cycle has left home once a joint is this many tolerances away
STILL = 0.05  # [rad/s] or [m/s]: back home means slower than this too


class CellTask:
    """The simulated cell's own task: a part picked and placed, a turn walked."""

    def __init__(self, cell):
        self._cell = cell
        self.finished = lambda state: cell.cycle_finished()

    def begin(self, index: int, t_ns: int) -> None:
        self._cell.begin_cycle(index)

    def end(self, t_ns: int, stopped: bool) -> dict:
        return self._cell.end_cycle()


class _Timed:
    """Outcome common to the hardware sources: success and the cycle time."""

    def begin(self, index: int, t_ns: int) -> None:
        self._t0, self._done = t_ns, False

    def end(self, t_ns: int, stopped: bool) -> dict:
        return {"success": self._done and not stopped, "cycle_time_s": (t_ns - self._t0) * 1e-9}


class DigitalInput(_Timed):
    """The cycle ends on a rising edge of the robot's digital input ``name``."""

    def __init__(self, robot, name: str):
        if not hasattr(robot, "digital_input"):
            raise ScenarioError(f"cycle.source: 'input' needs a robot with digital inputs; {robot.name!r} has none")
        known = robot.digital_inputs
        if name not in known:  # refused before the record starts, not at the first cycle
            raise ScenarioError(f"cycle.input: {robot.name!r} has no digital input {name!r}; it has: "
                                f"{', '.join(known) or 'none'}")
        self._read, self._name = robot.digital_input, name

    def begin(self, index: int, t_ns: int) -> None:
        super().begin(index, t_ns)
        self._was = bool(self._read(self._name))

    def finished(self, state) -> bool:
        now = bool(self._read(self._name))
        rising, self._was = now and not self._was, now
        self._done = self._done or rising
        return rising


class HomeReturn(_Timed):
    """The cycle ends when the robot, having left ``home``, is back within ``tolerance`` and slow."""

    def __init__(self, home: np.ndarray, tolerance: float):
        self._home, self._tol = np.asarray(home, dtype=np.float64), float(tolerance)

    def begin(self, index: int, t_ns: int) -> None:
        super().begin(index, t_ns)
        self._left = False

    def finished(self, state) -> bool:
        away = float(np.abs(state.q - self._home).max())
        if not self._left:
            self._left = away > LEFT_HOME * self._tol
            return False
        self._done = away < self._tol and float(np.abs(state.qd).max()) < STILL
        return self._done


class PolicyEpisodeEnd(_Timed):
    """The cycle ends when the policy says its episode is over (``episode_done()``), once it has said it is not:
    on wall time the policy is reset on its worker's thread before its next call, so the last episode's end
    still reads true at the start of the next."""

    def __init__(self, policy):
        if not callable(getattr(policy, "episode_done", None)):
            raise ScenarioError(f"cycle.source: 'policy' needs a policy with episode_done(); {policy.source!r} has none")
        self._done_fn: Callable[[], bool] = policy.episode_done

    def begin(self, index: int, t_ns: int) -> None:
        super().begin(index, t_ns)
        self._running = False

    def finished(self, state) -> bool:
        done = bool(self._done_fn())
        self._running = self._running or not done
        self._done = done and self._running
        return self._done


class FixedTime(_Timed):
    """The cycle ends ``seconds`` after it began."""

    def __init__(self, seconds: float, period_ns: int, first_chunk_ns: int | None = None):
        """``first_chunk_ns``: how long after a cycle's start its first chunk is taken at the soonest, where known
        (``build.first_chunk_ns``): a cycle that ended before it had its request dropped and the policy reset as
        the next one began, cycle after cycle, and the robot never moved."""
        if seconds * 1e9 < 2 * period_ns:  # a cycle must hold at least a tick of motion
            raise ScenarioError(f"cycle.seconds: {seconds:g} s is shorter than two servo periods "
                                f"({2 * period_ns * 1e-9:g} s) of this robot")
        self._ns = round(seconds * 1e9)
        if first_chunk_ns is not None and self._ns <= first_chunk_ns:
            raise ScenarioError(f"cycle.seconds: {seconds:g} s ends every cycle before its first chunk, taken "
                                f"{first_chunk_ns * 1e-6:g} ms after the cycle's start (simulated inference): the "
                                f"robot would never move; give more than {first_chunk_ns * 1e-9:g} s")

    def finished(self, state) -> bool:
        self._done = state.t_ns - self._t0 >= self._ns
        return self._done


class OnSimulatedCell:
    """A hardware source on a simulated cell: it ends the cycle; the cell presents the part and judges it."""

    def __init__(self, source, cell):
        self._source, self._cell = source, cell
        self.finished = source.finished

    def begin(self, index: int, t_ns: int) -> None:
        self._cell.begin_cycle(index)
        self._source.begin(index, t_ns)

    def end(self, t_ns: int, stopped: bool) -> dict:
        ended = self._source.end(t_ns, stopped)
        judged = self._cell.end_cycle()
        return {**judged, **ended, "success": bool(judged["success"] and ended["success"])}


def make_cycle_source(settings, robot, policy, first_chunk_ns: int | None = None):
    """The source the scenario's ``cycle:`` section names, for this robot and policy (``first_chunk_ns``: see
    ``FixedTime``)."""
    source = settings.source
    simulated = hasattr(robot, "cycle_finished")
    if source == "task":
        if not simulated:
            raise ScenarioError(f"cycle.source: 'task' needs a simulated cell; for {robot.name!r} choose "
                                "input, home, policy or time")
        return CellTask(robot)
    if source == "input":
        made = DigitalInput(robot, settings.input)
    elif source == "home":
        home = getattr(robot, "q_home", None)
        if home is None:
            raise ScenarioError(f"cycle.source: 'home' needs a home pose; {robot.name!r} has none")
        made = HomeReturn(home, settings.tolerance)
    elif source == "policy":
        made = PolicyEpisodeEnd(policy)
    else:
        made = FixedTime(settings.seconds, robot.dt_ns, first_chunk_ns)
    return OnSimulatedCell(made, robot) if simulated else made
