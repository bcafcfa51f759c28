"""Inference on its own thread, so the servo loop never waits for a policy.

The servo loop asks ``wants_observation(t_ns)`` each tick: true when no request is in flight
and the steps left in the newest chunk fall to ``threshold`` of its horizon (LeRobot's async
client uses 0.5). It then ``submit``s the observation and goes on; a later tick ``take``s the
chunk, stamped with the observation's time, and pushes it to the executor, which drops the
steps already past. Every chunk carries its latency and the queue depth (steps left) at the
moment it was asked for; a failed call is kept as an error, never raised on the servo path.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellguard.errors import ConfigError
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy
from cellguard.robot.state import Observation


@dataclass(frozen=True)
class InferenceResult:
    """One answered (or failed) request; times are the ``clock``'s [ns]."""

    chunk: ActionChunk | None
    error: str | None
    t_obs_ns: int
    t_submit_ns: int
    t_done_ns: int
    queue_depth: int  # steps left in the newest chunk when the observation was sent

    @property
    def latency_ns(self) -> int:
        return self.t_done_ns - self.t_submit_ns


class AsyncInference:
    """One worker thread running ``policy.infer``; at most one request in flight."""

    def __init__(self, policy: Policy, threshold: float = 0.5, clock: Callable[[], int] = time.monotonic_ns):
        if not 0.0 <= threshold <= 1.0:
            raise ConfigError(f"async inference: threshold must be in [0, 1], got {threshold}")
        self.policy, self.threshold, self.clock = policy, threshold, clock
        self.results: list[InferenceResult] = []
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._request: tuple[Observation, int, int] | None = None
        self._done: InferenceResult | None = None
        self._in_flight = False
        self._closed = False
        self._step_times = np.zeros(0, dtype=np.int64)  # of the newest chunk taken
        self._thread = threading.Thread(target=self._work, name="cellguard-inference", daemon=True)
        self._thread.start()

    def remaining_steps(self, t_ns: int) -> int:
        """Steps of the newest taken chunk that still lie after ``t_ns`` (the queue depth)."""
        return int(np.count_nonzero(self._step_times > t_ns))

    def wants_observation(self, t_ns: int) -> bool:
        """Whether the servo loop should hand over an observation at ``t_ns``."""
        if self._in_flight:
            return False
        horizon = len(self._step_times)
        return horizon == 0 or self.remaining_steps(t_ns) <= self.threshold * horizon

    def submit(self, observation: Observation) -> None:
        """Hand ``observation`` to the worker; returns at once."""
        with self._wake:
            if self._in_flight or self._closed:
                return
            self._request = (observation, self.clock(), self.remaining_steps(observation.t_ns))
            self._in_flight = True
            self._wake.notify()

    def take(self) -> InferenceResult | None:
        """The finished request, if any, once; its chunk's steps become the queue."""
        with self._lock:
            result, self._done = self._done, None
            if result is not None:
                self._in_flight = False
        if result is None:
            return None
        self.results.append(result)
        if result.chunk is not None:
            self._step_times = result.chunk.step_times_ns()
        return result

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the worker after its current call (bounded wait)."""
        with self._wake:
            self._closed = True
            self._wake.notify()
        self._thread.join(timeout_s)

    def _work(self) -> None:
        while True:
            with self._wake:
                while self._request is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                (observation, t_submit, depth), self._request = self._request, None
            chunk, error = None, None
            try:
                chunk = self.policy.infer(observation)
            except Exception as exc:  # a policy failure becomes a recorded result, never a dead servo loop
                error = f"{type(exc).__name__}: {exc}"
            with self._lock:
                self._done = InferenceResult(chunk, error, observation.t_ns, t_submit, self.clock(), depth)
