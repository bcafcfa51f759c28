"""AsyncInference: a real worker thread; chunks come back stamped, the servo side never blocks."""

import threading
import time

import numpy as np

from cellguard.policy.async_inference import AsyncInference
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.state import Observation


class GatedPolicy:
    """Answers only when the test opens the gate, so the test controls 'inference is slow'."""

    source = "gated"

    def __init__(self, horizon: int = 10):
        self.gate = threading.Event()
        self.horizon = horizon
        self.fail_next = False

    def reset(self) -> None:
        pass

    def content_hash(self) -> str:
        return "gated"

    def infer(self, observation: Observation) -> ActionChunk:
        assert self.gate.wait(5.0)
        self.gate.clear()
        if self.fail_next:
            self.fail_next = False
            raise RuntimeError("model exploded")
        actions = np.tile(observation.q, (self.horizon, 1))
        return ActionChunk(actions, observation.t_ns, 20_000_000)


def _obs(t_ns: int) -> Observation:
    return Observation(t_ns, np.full(6, t_ns * 1e-9), np.zeros(6))


def _wait_for(inference: AsyncInference):
    for _ in range(500):  # bounded: 5 s
        result = inference.take()
        if result is not None:
            return result
        time.sleep(0.01)
    raise AssertionError("no result")


def test_submit_returns_at_once_and_the_chunk_answers_the_observation_it_was_given():
    policy = GatedPolicy()
    inference = AsyncInference(policy, threshold=0.5)
    try:
        assert inference.wants_observation(0)
        inference.submit(_obs(1_000_000))  # returns although the policy is blocked
        assert not inference.wants_observation(2_000_000)  # one request in flight at most
        assert inference.take() is None
        policy.gate.set()
        result = _wait_for(inference)
        assert result.error is None and result.chunk.t_obs_ns == 1_000_000
        assert result.chunk.actions[0, 0] == 1e-3  # built from the submitted observation
        assert result.latency_ns > 0 and result.queue_depth == 0
    finally:
        policy.gate.set()
        inference.close()


def test_a_new_observation_is_wanted_when_the_steps_left_fall_to_the_threshold():
    policy = GatedPolicy(horizon=10)
    inference = AsyncInference(policy, threshold=0.5)
    try:
        inference.submit(_obs(0))
        policy.gate.set()
        _wait_for(inference)
        # steps at 20, 40, ..., 200 ms: more than 5 left until 100 ms
        assert inference.remaining_steps(50_000_000) == 8 and not inference.wants_observation(50_000_000)
        assert inference.remaining_steps(100_000_000) == 5 and inference.wants_observation(100_000_000)
        inference.submit(_obs(100_000_000))
        policy.gate.set()
        assert _wait_for(inference).queue_depth == 5
    finally:
        policy.gate.set()
        inference.close()


def test_a_failing_policy_is_recorded_not_raised_and_the_worker_keeps_serving():
    policy = GatedPolicy()
    policy.fail_next = True
    inference = AsyncInference(policy)
    try:
        inference.submit(_obs(0))
        policy.gate.set()
        failed = _wait_for(inference)
        assert failed.chunk is None and "model exploded" in failed.error
        inference.submit(_obs(5_000_000))
        policy.gate.set()
        assert _wait_for(inference).chunk is not None
        assert len(inference.results) == 2
    finally:
        policy.gate.set()
        inference.close()


def test_the_chunk_is_prepared_on_the_worker_thread_so_the_servo_tick_only_swaps_it_in():
    from cellguard.control.executor import Executor, PreparedChunk
    from cellguard.robot.registry import make_cell

    cell = make_cell("arm-pick-place")
    executor = Executor(cell.profile, cell.read().q, cell.dt_ns, tool=cell.tool_point)
    threads = []

    def prepare(chunk):
        threads.append(threading.current_thread().name)
        return executor.prepare(chunk)

    policy = GatedPolicy()
    inference = AsyncInference(policy, prepare=prepare)
    try:
        inference.submit(_obs(1_000_000))
        policy.gate.set()
        result = _wait_for(inference)
        assert threads == ["cellguard-inference"]
        assert isinstance(result.prepared, PreparedChunk) and result.prepared.problem is None
        reference = executor.prepare(result.chunk)  # the same fit as on the servo thread, tool speeds included
        assert np.array_equal(result.prepared.tool_speed, reference.tool_speed)
        assert np.array_equal(result.prepared.curve.points, reference.curve.points)
    finally:
        policy.gate.set()
        inference.close()


def test_a_new_episode_resets_the_policy_on_the_workers_thread_before_its_next_call_never_during_one():
    """Reset from the servo thread, it cleared a scripted policy's state in the middle of the worker's call."""
    class Recording(GatedPolicy):
        def __init__(self):
            super().__init__()
            self.calls: list[tuple[str, str]] = []

        def reset(self) -> None:
            self.calls.append(("reset", threading.current_thread().name))

        def infer(self, observation: Observation) -> ActionChunk:
            self.calls.append(("infer", threading.current_thread().name))
            chunk = super().infer(observation)
            self.calls.append(("answered", threading.current_thread().name))
            return chunk

    policy = Recording()
    inference = AsyncInference(policy, threshold=0.5)
    try:
        inference.submit(_obs(1_000_000))
        while not policy.calls:
            time.sleep(0.001)
        inference.discard()  # a new cycle while the call is in flight
        assert [c for c, _ in policy.calls] == ["infer"]  # nothing reset under it
        policy.gate.set()
        _wait_for(inference)
        inference.submit(_obs(2_000_000))
        policy.gate.set()
        _wait_for(inference)
        assert [c for c, _ in policy.calls] == ["infer", "answered", "reset", "infer", "answered"]
        assert {thread for _, thread in policy.calls} == {"cellguard-inference"}
    finally:
        inference.close()
