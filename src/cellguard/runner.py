"""The tick path end to end: policy -> executor -> envelope -> robot, one cycle after another.

Inference is simulated off the servo path in simulated time: a request is sent at the policy's
cadence, one at a time, and its chunk reaches the executor ``latency`` later, stamped with the
time of the observation it answers. The servo loop never waits for it. The wall-clock time of
each real ``infer`` call is measured too and kept per cycle (``outcome["inference"]``); the
threaded form for a real-time loop is ``cellguard.policy.async_inference``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cellguard.control.events import Event
from cellguard.control.settings import build_guard
from cellguard.diagnose.cycle_buffer import CycleBuffer
from cellguard.diagnose.features import cycle_features
from cellguard.errors import RecordError
from cellguard.output import make_folder
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.registry import make_policy
from cellguard.record.session import RunRecording
from cellguard.robot.registry import make_cell
from cellguard.scenario import Scenario

NOMINAL_INFERENCE_S = 0.010  # simulated inference latency of a healthy policy [s]
CYCLE_TIMEOUT_S = 12.0  # a cycle that has not finished by then is ended as failed [s]
NAN_AFTER_S = 1.0  # a policy_nan fault corrupts the first chunk this long into its cycle [s]
STOP_SETTLE_S = 0.3  # a category 2 stop holds the measured position this long before the run ends [s]


class Run:
    """One scenario on one simulated cell; ``cycle()`` runs the next cycle to its end."""

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.cell = make_cell(scenario.cell, seed=scenario.seed)
        scenario.check_against(self.cell)
        self.policy = make_policy(scenario.policy, self.cell)
        self.guard = build_guard(self.cell, scenario.guard)
        self.events: list[Event] = []
        self.cycles: list[dict] = []
        self._period_ns = round(1e9 / scenario.policy_hz)
        self.ticks = CycleBuffer(self.cell.profile.dof, round(CYCLE_TIMEOUT_S * 1e9 / self.cell.dt_ns) + 1)
        self.recording: RunRecording | None = None  # set by run_scenario, fed every tick
        self.stopped: str | None = None  # why the run stopped early (category 2), if it did

    def cycle(self) -> dict:
        """Run the next cycle; return its outcome (success, timing, measured poses)."""
        index = len(self.cycles)
        cell, guard, ticks = self.cell, self.guard, self.ticks
        for fault in self.scenario.faults:
            fault.apply(cell, index)
        latency_ns = round((NOMINAL_INFERENCE_S + sum(f.extra_latency_s(index) for f in self.scenario.faults)) * 1e9)
        corrupt = any(f.corrupts_output(index) for f in self.scenario.faults)
        cell.begin_cycle(index)
        self.policy.reset()
        start = cell.read().t_ns
        rec = self.recording
        if rec is not None:
            rec.begin_cycle(index, self._phase(index), start)
        timeout = start + round(CYCLE_TIMEOUT_S * 1e9)
        next_request = start
        pending: tuple[int, ActionChunk] | None = None
        first_event, latencies, wall_ns = len(self.events), [], []
        ticks.clear()
        if not guard.power:  # a category 0/1 stop in the last cycle: the operator resets the cell
            cell.set_power(True)
            guard.reset(cell.read().q)
            self.events.append(Event(start, "reset", "operator reset after a stop with power removed"))
        state = cell.read()
        while True:
            t = cell.t_ns
            if pending is not None and pending[0] <= t:
                if rec is not None:
                    rec.chunk(pending[1], t, latency_ns)
                self.events.extend(guard.push(pending[1], t))
                pending = None
            if pending is None and t >= next_request:
                next_request = t + self._period_ns
                began = time.perf_counter_ns()
                try:
                    chunk = self.policy.infer(observation := cell.observe())
                except Exception as exc:  # noqa: BLE001 - a failing policy is an event; the watchdog stops the cell
                    self.events.append(Event(t, "inference_failed", f"{type(exc).__name__}: {exc}"))
                    chunk = None
                wall_ns.append(time.perf_counter_ns() - began)
                if chunk is not None:
                    if rec is not None:
                        rec.request(t, observation)
                    if corrupt and t - start >= NAN_AFTER_S * 1e9:
                        chunk, corrupt = _with_nan(chunk), False
                    pending = (t + latency_ns, chunk)
                    latencies.append(latency_ns)
            setpoint, events = guard.tick(t, state, cell.safety())
            if events:
                self.events.extend(events)
                if not guard.power:
                    cell.set_power(False)
            sent = cell.write(setpoint)
            cell.step()
            state = cell.read()
            ticks.add(guard.reference, sent, state)
            if rec is not None and not rec.tick(guard.reference, sent, state):
                break
            if cell.cycle_finished() or cell.t_ns >= timeout:
                break
        outcome = {"cycle": index, "phase": self._phase(index), **cell.end_cycle()}
        outcome["timed_out"] = cell.t_ns >= timeout
        outcome["inference"] = _wall_latency(wall_ns)
        outcome["features"] = cycle_features(cell.profile, ticks, outcome, latencies, self.events[first_event:])
        if rec is not None:
            rec.end_cycle(outcome, cell.t_ns)
            if rec.failed:
                self._stop_unrecorded(rec.failed)
        self.cycles.append(outcome)
        return outcome

    def _stop_unrecorded(self, why: str) -> None:
        """Category 2 stop when the record cannot be written: hold the measured position, power kept."""
        t = self.cell.t_ns
        self.cell.write(self.cell.read().q)
        for _ in range(round(STOP_SETTLE_S * 1e9 / self.cell.dt_ns)):
            self.cell.step()
        self.events.append(Event(t, "record_failed", f"an unrecorded run is not allowed: {why}", category=2))
        self.stopped = why

    def _phase(self, index: int) -> str:
        return "acceptance" if index < self.scenario.acceptance_cycles else "production"

    def summary(self) -> dict:
        """Per-cycle outcomes, events, and the injected faults as ground truth, kept apart."""
        by_phase = {}
        for phase in ("acceptance", "production"):
            done = [c["success"] for c in self.cycles if c["phase"] == phase]
            by_phase[phase] = {"cycles": len(done), "success_rate": float(np.mean(done)) if done else None}
        return {
            "scenario": self.scenario.model_dump(mode="json", exclude={"faults"}),
            "context": {**self.cell.context(), "policy": self.policy.source,
                        "policy_sha256": self.policy.content_hash(), "profile_sha256": self.cell.profile.sha256},
            "phases": by_phase,
            "cycles": self.cycles,
            "events": [e.to_dict() for e in self.events],
            "ground_truth": {"faults": [f.model_dump(mode="json") for f in self.scenario.faults]},
        }


def run_scenario(scenario: Scenario, out: Path, on_cycle: Callable[[dict], None] | None = None,
                 make_run: Callable[[Scenario], Run] = Run) -> dict:
    """Run every cycle of ``scenario`` and write ``out/summary.json``; return the summary.
    ``make_run`` builds the run (a subclass, e.g. the release's shadow run, may observe it)."""
    out = make_folder(Path(out), "--out")
    run = make_run(scenario)
    run.recording = RunRecording.start(out, run)  # RecordError here: nothing runs
    try:
        for _ in range(scenario.total_cycles):
            outcome = run.cycle()
            if on_cycle is not None:
                on_cycle(outcome)
            if run.stopped:
                break
    finally:
        run.recording.close()
    summary = run.summary()
    if run.stopped:
        summary["stopped"] = run.stopped
    try:
        (out / "summary.json").write_text(json.dumps(summary, indent=1))
    except OSError as exc:
        raise RecordError(f"{out / 'summary.json'}: cannot write ({exc.strerror}); "
                          f"run stopped: {run.stopped or 'no'}") from None
    return summary


def _with_nan(chunk: ActionChunk) -> ActionChunk:
    actions = np.array(chunk.actions, dtype=np.float64)
    actions[actions.shape[0] // 2:, 1] = np.nan
    return ActionChunk(actions, chunk.t_obs_ns, chunk.dt_ns, chunk.uncertainty)


def _wall_latency(wall_ns: list[int]) -> dict:
    """Measured (wall-clock) inference time of the cycle's chunks; kept out of the drift features."""
    ms = np.asarray(wall_ns, dtype=np.float64) * 1e-6
    return {"chunks": len(wall_ns), "wall_ms_mean": float(ms.mean()) if len(ms) else 0.0,
            "wall_ms_p99": float(np.percentile(ms, 99)) if len(ms) else 0.0, "wall_ms_max": float(ms.max()) if len(ms) else 0.0}
