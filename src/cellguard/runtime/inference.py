"""Inference as the tick loop sees it: ``due``, ``submit``, ``take``, never a wait on the servo path.

``SimulatedInference`` (simulated time): a request at the policy's cadence, one at a time; the
policy is called at once and its chunk reaches the loop ``latency_ns`` later in simulated time
(the latency a fault may raise). ``WorkerInference`` (wall time): the policy runs on its own
thread or process (``policy.async_inference``) and the chunk arrives when it is done; a worker whose
process ended, or whose call has run ``hang_ns``, has lost its policy: that is one arrival (``lost``)
and no request follows. Both measure the wall time of every call.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

from cellguard.policy.chunk import ActionChunk

NOMINAL_INFERENCE_S = 0.010  # simulated inference latency of a healthy policy [s]
NEVER = 1 << 62  # a time no tick reaches [ns]


@dataclass(frozen=True)
class Arrival:
    """A finished request: the chunk (None if the call failed), its latency [ns], the error."""

    chunk: ActionChunk | None
    latency_ns: int
    wall_ns: int
    error: str | None = None
    prepared: object | None = None  # the chunk checked and fitted off the servo thread, if it was
    lost: bool = False  # the policy answers no more (its process ended, a call hung): ``error`` says why


class SimulatedInference:
    """A request every ``period_ns`` while none is pending; the chunk arrives ``latency_ns`` later."""

    def __init__(self, policy, period_ns: int):
        self.policy, self.period_ns = policy, int(period_ns)
        self.latency_ns = round(NOMINAL_INFERENCE_S * 1e9)
        self._pending: tuple[int, Arrival] | None = None
        self._next = 0

    def begin_cycle(self, t_ns: int) -> None:
        """A new episode: nothing pending, the policy reset."""
        self._pending, self._next = None, t_ns
        self.policy.reset()

    def due(self, t_ns: int) -> bool:
        return self._pending is None and t_ns >= self._next

    def submit(self, t_ns: int, observation) -> Arrival | None:
        """Call the policy now; a failure comes back at once (an Arrival with its error)."""
        self._next = t_ns + self.period_ns
        began = time.perf_counter_ns()
        try:
            chunk = self.policy.infer(observation)
        except Exception as exc:  # noqa: BLE001 - a failing policy is an event; the watchdog stops the cell
            return Arrival(None, 0, time.perf_counter_ns() - began, f"{type(exc).__name__}: {exc}")
        self._pending = (t_ns + self.latency_ns, Arrival(chunk, self.latency_ns, time.perf_counter_ns() - began))
        return None

    def spacing_ns(self, taken_ns: int, chunk: ActionChunk) -> int:
        """The longest time from one observation to the next when a chunk is taken ``taken_ns`` after its
        observation [ns]: the next request waits for it and for the policy's period (``chunk``: unused here)."""
        return max(self.period_ns, taken_ns)

    def corrupt_pending(self, corrupt: Callable[[ActionChunk], ActionChunk]) -> None:
        """Replace the pending chunk by ``corrupt(chunk)`` (a simulated fault in the policy's output)."""
        at, arrival = self._pending
        self._pending = (at, Arrival(corrupt(arrival.chunk), arrival.latency_ns, arrival.wall_ns))

    def take(self, t_ns: int) -> Arrival | None:
        if self._pending is not None and self._pending[0] <= t_ns:
            arrival, self._pending = self._pending[1], None
            return arrival
        return None

    def close(self) -> None:
        """Nothing runs in the background."""


class WorkerInference:
    """The policy on a worker (thread or process); the chunk arrives when the worker is done. A request goes
    when the worker wants one (the chunk runs low) and at most once per ``period_ns`` (the policy's cadence):
    a failed request was retried on every servo tick, a thousand calls a second to a remote policy."""

    def __init__(self, worker, period_ns: int):
        self.worker, self.period_ns = worker, int(period_ns)
        self._next = 0
        self._corrupt: Callable[[ActionChunk], ActionChunk] | None = None
        self.extra_ns = 0  # a simulated cell's policy_latency fault on wall time: each chunk held back this long
        self._held: tuple[int, object] | None = None  # (due [ns], the worker's result) while held back
        self.hang_ns = NEVER  # a call not answered this long after its request has hung (the loop sets it) [ns]
        self.lost: str | None = None  # why the policy is asked no more (its process ended, a call hung)
        self._answer_by = NEVER  # past it, the last request may have hung: the worker is asked [ns]

    def warm_up(self, observation, timeout_s: float, stop: Callable[[], bool]) -> None:
        """A first call off the clock (a cold policy's first answer is not its latency), waited for at most
        ``timeout_s`` and until ``stop()``. A call given up, or a process that ended or could not build the policy,
        loses the policy (a failed call does not: a cold server may answer the next)."""
        if not self.worker.warm_up(observation, timeout_s, stop):
            self._lose("the policy's first call was given up at a stop" if stop() else
                       f"the policy's first call has not answered in {timeout_s:g} s")
        elif self.worker.ended:
            self._lose(self.worker.ended)

    def begin_cycle(self, t_ns: int) -> None:
        """A new episode: the worker drops what it holds and resets the policy on its own thread."""
        self.worker.discard()
        self._next = t_ns if self.lost is None else NEVER

    def due(self, t_ns: int) -> bool:
        return self._held is None and t_ns >= self._next and self.worker.wants_observation(t_ns)

    def submit(self, t_ns: int, observation) -> Arrival | None:
        self._next = t_ns + self.period_ns
        self._answer_by = t_ns + self.hang_ns
        self.worker.submit(observation)
        return None

    def spacing_ns(self, taken_ns: int, chunk: ActionChunk) -> int:
        """The longest time from one observation to the next when ``chunk`` is taken ``taken_ns`` after its
        observation [ns]: the next request waits for it, for the policy's period and for the worker (until
        ``chunk`` runs low: half its horizon, as LeRobot's async client)."""
        return max(self.period_ns, taken_ns, self.worker.wait_ns(chunk))

    def corrupt_pending(self, corrupt: Callable[[ActionChunk], ActionChunk]) -> None:
        """The next chunk to arrive becomes ``corrupt(chunk)`` (a simulated fault in the policy's output, on
        wall time: a --realtime run of a simulated cell)."""
        self._corrupt = corrupt

    def take(self, t_ns: int) -> Arrival | None:
        if t_ns > self._answer_by:  # one compare a tick
            return self._overdue(t_ns)
        result = self._late(t_ns) if self.extra_ns else self.worker.take()
        if result is None:
            return None
        if result.chunk is None and self.worker.ended:  # every later call would fail the same way
            return self._lose(self.worker.ended)
        chunk, prepared = result.chunk, result.prepared
        if self._corrupt is not None and chunk is not None:  # unprepared: the guard checks it as it arrives
            chunk, prepared, self._corrupt = self._corrupt(chunk), None, None
        return Arrival(chunk, result.latency_ns, result.latency_ns, result.error, prepared)

    def _late(self, t_ns: int):
        """The worker's result once ``extra_ns`` has passed since it came (its latency counts the wait)."""
        if self._held is None:
            result = self.worker.take()
            if result is None:
                return None
            self._held = (t_ns + self.extra_ns, result)
        due, result = self._held
        if t_ns < due:
            return None
        self._held = None
        return replace(result, t_done_ns=result.t_done_ns + self.extra_ns)

    def _overdue(self, t_ns: int) -> Arrival | None:
        """``hang_ns`` since the last request: the policy lost if the worker is still in that call, else (it
        answered, or its answer was dropped at a new episode) nothing is overdue. A lost policy gives nothing
        (a hung call's late chunk included)."""
        if self.lost is not None:
            return None
        if self.worker.busy:
            return self._lose(f"the policy's call has not answered in {self.hang_ns * 1e-9:.1f} s")
        self._answer_by = NEVER
        return self.take(t_ns)

    def _lose(self, why: str) -> Arrival:
        """The policy answers no more: no request follows; the one arrival that says so."""
        self.lost, self._answer_by, self._next = why, -NEVER, NEVER
        return Arrival(None, 0, 0, why, lost=True)

    def close(self) -> None:
        """Stop the worker; a lost policy's call is not waited for (a hung one held the run's end 5 s)."""
        if self.lost is None:
            self.worker.close()
        else:
            self.worker.close(timeout_s=0.0)
