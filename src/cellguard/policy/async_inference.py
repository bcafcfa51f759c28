"""Inference on its own thread, so the servo loop never waits for a policy.

The servo loop asks ``wants_observation(t_ns)`` each tick: true when no request is in flight
and the steps left in the newest chunk fall to ``threshold`` of its horizon (LeRobot's async
client uses 0.5). It then ``submit``s the observation and goes on; a later tick ``take``s the
chunk, stamped with the observation's time, and pushes it to the executor, which drops the
steps already past. A ``prepare`` callable (the executor's: checks, the chunk's curve, its tool
speeds by forward kinematics, about a millisecond for 50 steps) runs on the worker thread too, so
the servo tick that takes the chunk only swaps it in. Every chunk carries its latency and the queue depth (steps left) at the
moment it was asked for; a failed call is kept as an error, never raised on the servo path.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from collections import deque
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellguard.errors import ConfigError
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy
from cellguard.robot.state import Observation
from cellguard.threads import start_process, start_thread

RESULTS_KEPT = 1000  # newest results kept in memory; the record holds every chunk
WAIT_S = 0.1  # a warm-up waiting for its answer asks whether to stop this often [s] (an operator's Ctrl-C)


@dataclass(frozen=True)
class InferenceResult:
    """One answered (or failed) request; times are the ``clock``'s [ns]."""

    chunk: ActionChunk | None
    error: str | None
    t_obs_ns: int
    t_submit_ns: int
    t_done_ns: int
    queue_depth: int  # steps left in the newest chunk when the observation was sent
    prepared: object | None = None  # ``prepare(chunk)``, done on the worker thread (None: not prepared)

    @property
    def latency_ns(self) -> int:
        return self.t_done_ns - self.t_submit_ns


class PolicyProcess:
    """A policy built by ``factory`` (picklable, e.g. a ``functools.partial``) in its own process.

    A pure-Python policy holds the GIL while it computes; in its own process it cannot stall
    the servo thread. ``infer`` sends the observation over a pipe and waits for the chunk (the
    waiting thread releases the GIL); an exception in the child comes back as a RuntimeError.
    ``ended`` says why once the process is found gone, or holds no policy it may run (one it could not build, or
    not the run's), or the OS refused to start it: it answers no more.
    """

    def __init__(self, factory: Callable[[], Policy], sha256: str | None = None):
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(target=_serve_policy, args=(child, factory, sha256), name="cellguard-policy",
                                    daemon=True)
        self.ended: str | None = start_process(self._process)  # EAGAIN was a traceback through here
        child.close()

    def reset(self) -> None:
        try:
            self._conn.send(("reset", None))
        except OSError:
            raise self._ended() from None
        self._answer()

    def infer(self, observation: Observation) -> ActionChunk:
        try:
            self._conn.send(("infer", observation))
        except OSError:
            raise self._ended() from None
        return self._answer()

    def _answer(self):
        try:
            kind, value = self._conn.recv()
        except (EOFError, OSError):
            raise self._ended() from None
        if kind == "broken":  # the policy could not be built there, or is not the run's: it answers no more
            self.ended = value
        if kind in ("error", "broken"):
            raise RuntimeError(value)
        return value

    def _ended(self) -> RuntimeError:
        self._process.join(1.0)  # reaped, its exit code is known (it read None)
        self.ended = f"policy process ended (exit code {self._process.exitcode})"
        return RuntimeError(self.ended)

    def close(self, timeout_s: float = 5.0) -> None:
        """Ask the process to close its policy; killed if it has not ended after ``timeout_s``."""
        if self._process.pid is None:  # never started (``ended``): nothing to ask, join or kill
            self._conn.close()
            return
        try:
            self._conn.send(("close", None))
        except OSError:
            pass
        self._process.join(timeout_s)
        if self._process.is_alive():
            self._process.kill()


def _serve_policy(conn, factory, sha256: str | None) -> None:
    """Answer the parent's requests. The policy is loaded again here; unless its content hash is ``sha256``
    (the copy the run checked, recorded and released) it is not run: its file changed in between."""
    for signum in (signal.SIGINT, signal.SIGHUP):  # a terminal's Ctrl-C and hangup reach the whole group: the
        signal.signal(signum, signal.SIG_IGN)  # loop decides
    try:
        policy, broken = factory(), None
        loaded = policy.content_hash() if sha256 is not None else None
        if loaded != sha256:
            broken = (f"policy in the inference process is not the run's: sha256 {loaded[:12]}, the run loaded "
                      f"{sha256[:12]} (its source changed meanwhile)")
    except Exception as exc:  # noqa: BLE001 - every request is answered with why the policy is missing
        policy, broken = None, f"policy could not be built: {type(exc).__name__}: {exc}"
    while True:
        kind, value = conn.recv()
        if broken is not None and kind != "close":
            conn.send(("broken", broken))  # for good: the parent asks no more
            continue
        if kind == "close":
            close = getattr(policy, "close", None)
            if callable(close):
                close()
            return
        try:
            conn.send(("ok", policy.reset() if kind == "reset" else policy.infer(value)))
        except Exception as exc:  # noqa: BLE001 - reported to the parent as the call's error
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


class AsyncInference:
    """One worker thread running ``policy.infer``; at most one request in flight.

    ``worker="process"`` runs the policy built by ``factory`` in its own process instead (the
    thread only waits on the pipe); ``policy`` is then the parent's copy, for its hash and source.
    """

    def __init__(self, policy: Policy, threshold: float = 0.5, clock: Callable[[], int] = time.monotonic_ns,
                 worker: str = "thread", factory: Callable[[], Policy] | None = None,
                 prepare: Callable[[ActionChunk], object] | None = None):
        if not 0.0 <= threshold <= 1.0:
            raise ConfigError(f"async inference: threshold must be in [0, 1], got {threshold}")
        if worker not in ("thread", "process") or (worker == "process" and factory is None):
            raise ConfigError(f"async inference: worker must be 'thread' or 'process' (with a factory), got {worker!r}")
        self.policy, self.threshold, self.clock, self._prepare = policy, threshold, clock, prepare
        self._remote = PolicyProcess(factory, policy.content_hash()) if worker == "process" else None
        self._reset = False  # a new episode: the worker resets the policy before its next call
        self.results: deque[InferenceResult] = deque(maxlen=RESULTS_KEPT)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._answered = threading.Condition(self._lock)  # a result is done (a warm-up waits for it)
        self._request: tuple[Observation, int, int] | None = None
        self._done: InferenceResult | None = None
        self._in_flight = False
        self._closed = False
        self._set_queue(np.zeros(0, dtype=np.int64))  # step times of the newest chunk taken [ns]
        self._thread = threading.Thread(target=self._work, name="cellguard-inference", daemon=True)
        # its process or thread refused: the warm-up answers at once; ``ended`` says why
        self._unstarted = (self._remote and self._remote.ended) or start_thread(self._thread)
        if self._unstarted is not None:
            self._unstarted = f"the policy's inference worker: {self._unstarted}"
            if self._remote is not None:
                self._remote.close(0.0)

    def remaining_steps(self, t_ns: int) -> int:
        """Steps of the newest taken chunk that still lie after ``t_ns`` (the queue depth)."""
        return int(np.count_nonzero(self._step_times > t_ns))

    def wants_observation(self, t_ns: int) -> bool:
        """Whether the servo loop should hand over an observation at ``t_ns`` (asked every tick: one compare)."""
        return not self._in_flight and t_ns >= self._due_ns

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
            self._set_queue(result.chunk.step_times_ns())
        return result

    def wait_ns(self, chunk: ActionChunk) -> int:
        """How long after ``chunk``'s observation the next one is due, once the chunk is the queue [ns] (the
        start-up check counts it: at a threshold of 0.5 the next chunk is asked for half a horizon in)."""
        return max(self._due(chunk.step_times_ns()) - chunk.t_obs_ns, 0)

    def _set_queue(self, step_times: np.ndarray) -> None:
        """The newest chunk's step times [ns], ascending, and when an observation is due."""
        self._step_times = step_times
        self._due_ns = self._due(step_times)

    def _due(self, step_times: np.ndarray) -> int:
        """When an observation is due for a chunk with these step times [ns]: from the time at which at most
        ``threshold`` of the horizon is left (``remaining_steps(t) <= threshold * horizon``)."""
        horizon = len(step_times)
        keep = int(np.floor(self.threshold * horizon))  # steps that may still lie ahead when asking
        return -(1 << 62) if keep >= horizon else int(step_times[horizon - 1 - keep])

    @property
    def busy(self) -> bool:
        """A call asked for and not answered yet (one answered and not taken is not busy)."""
        return self._in_flight and self._done is None

    @property
    def ended(self) -> str | None:
        """Why the policy answers no more: its worker thread or process never started, its process ended."""
        return self._unstarted or (None if self._remote is None else self._remote.ended)

    def warm_up(self, observation: Observation, timeout_s: float, stop: Callable[[], bool] = lambda: False) -> bool:
        """One call before the loop starts (loads, compiles, fills caches), on the worker; its chunk is dropped.
        Waited for at most ``timeout_s`` and until ``stop()``, asked every ``WAIT_S`` (called on the main thread,
        a policy hung in it hung the run, deaf to SIGTERM). True once answered, a failure too (the loop's first
        request reports it; a policy its process could not build ends the worker: ``ended``); False: given up, the
        call still in flight."""
        if self._unstarted is not None:
            return True
        self.submit(observation)
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while self._done is None:
                left = deadline - time.monotonic()
                if left <= 0 or stop():
                    return False
                self._answered.wait(min(left, WAIT_S))
            self._done, self._in_flight = None, False
        return True

    def discard(self) -> None:
        """A new episode: forget the queue and a finished result (one still in flight arrives late); the
        worker resets the policy before its next call (reset from the servo thread, it cleared a scripted
        policy's state in the middle of the worker's call: TypeError in the record)."""
        with self._lock:
            if self._done is not None:
                self._done, self._in_flight = None, False
            self._reset = True
        self._set_queue(np.zeros(0, dtype=np.int64))

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the worker after its current call (bounded wait); a policy process still in its call then is
        killed at once (it would answer the call before it reads the close)."""
        with self._wake:
            self._closed = True
            self._wake.notify()
        if self._unstarted is not None:
            return  # no thread to join; its process, if any, never started or killed as the thread was refused
        self._thread.join(timeout_s)
        if self._remote is not None:
            self._remote.close(0.0 if self._thread.is_alive() else timeout_s)

    def _work(self) -> None:
        while True:
            with self._wake:
                while self._request is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                (observation, t_submit, depth), self._request = self._request, None
                reset, self._reset = self._reset, False
            chunk, error, prepared = None, None, None
            try:
                policy = self.policy if self._remote is None else self._remote
                if reset:
                    policy.reset()
                chunk = policy.infer(observation)
            except Exception as exc:  # a policy failure becomes a recorded result, never a dead servo loop
                error = f"{type(exc).__name__}: {exc}"
            t_done = self.clock()  # the policy's latency ends here; preparing is the loop's own work
            if chunk is not None and self._prepare is not None:
                try:
                    prepared = self._prepare(chunk)
                except Exception as exc:  # noqa: BLE001 - a failed call, as if the policy had failed
                    chunk, error = None, f"preparing the chunk: {type(exc).__name__}: {exc}"
            with self._lock:
                self._done = InferenceResult(chunk, error, observation.t_ns, t_submit, t_done, depth, prepared)
                self._answered.notify()
