"""The tick path end to end: policy -> executor -> envelope -> robot, one cycle after another.

Inference is simulated off the servo path in simulated time: a request is sent at the policy's
cadence, one at a time, and its chunk reaches the executor ``latency`` later, stamped with the
time of the observation it answers. The servo loop never waits for it.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cellguard.control.envelope import Envelope
from cellguard.control.events import Event
from cellguard.control.executor import Executor
from cellguard.diagnose.cycle_buffer import CycleBuffer
from cellguard.diagnose.features import cycle_features
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.registry import make_policy
from cellguard.robot.registry import make_cell
from cellguard.scenario import Scenario

NOMINAL_INFERENCE_S = 0.010  # simulated inference latency of a healthy policy [s]
CYCLE_TIMEOUT_S = 12.0  # a cycle that has not finished by then is ended as failed [s]
NAN_AFTER_S = 1.0  # a policy_nan fault corrupts the first chunk this long into its cycle [s]


class Run:
    """One scenario on one simulated cell; ``cycle()`` runs the next cycle to its end."""

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.cell = make_cell(scenario.cell, seed=scenario.seed)
        scenario.check_against(self.cell)
        self.policy = make_policy(scenario.policy, self.cell)
        self.executor = Executor(self.cell.profile, self.cell.read().q)
        self.envelope = Envelope(self.cell.profile)
        self.events: list[Event] = []
        self.cycles: list[dict] = []
        self._period_ns = round(1e9 / scenario.policy_hz)
        self.ticks = CycleBuffer(self.cell.profile.dof, round(CYCLE_TIMEOUT_S * 1e9 / self.cell.dt_ns) + 1)

    def cycle(self) -> dict:
        """Run the next cycle; return its outcome (success, timing, measured poses)."""
        index = len(self.cycles)
        cell, executor, envelope, ticks = self.cell, self.executor, self.envelope, self.ticks
        for fault in self.scenario.faults:
            fault.apply(cell, index)
        latency_ns = round((NOMINAL_INFERENCE_S + sum(f.extra_latency_s(index) for f in self.scenario.faults)) * 1e9)
        corrupt = any(f.corrupts_output(index) for f in self.scenario.faults)
        cell.begin_cycle(index)
        self.policy.reset()
        start = cell.read().t_ns
        timeout = start + round(CYCLE_TIMEOUT_S * 1e9)
        next_request = start
        pending: tuple[int, ActionChunk] | None = None
        first_event, latencies = len(self.events), []
        ticks.clear()
        while True:
            t = cell.t_ns
            if pending is not None and pending[0] <= t:
                self.events.extend(executor.push(pending[1], t))
                pending = None
            if pending is None and t >= next_request:
                chunk = self.policy.infer(cell.observe())
                if corrupt and t - start >= NAN_AFTER_S * 1e9:
                    chunk, corrupt = _with_nan(chunk), False
                pending = (t + latency_ns, chunk)
                latencies.append(latency_ns)
                next_request = t + self._period_ns
            reference = executor.reference(t)
            setpoint, events = envelope.apply(t, reference)
            if events:
                self.events.extend(events)
            sent = cell.write(setpoint)
            cell.step()
            ticks.add(reference, sent, cell.read())
            if cell.cycle_finished() or cell.t_ns >= timeout:
                break
        outcome = {"cycle": index, "phase": self._phase(index), **cell.end_cycle()}
        outcome["timed_out"] = cell.t_ns >= timeout
        outcome["features"] = cycle_features(cell.profile, ticks, outcome, latencies, self.events[first_event:])
        self.cycles.append(outcome)
        return outcome

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


def run_scenario(scenario: Scenario, out: Path, on_cycle: Callable[[dict], None] | None = None) -> dict:
    """Run every cycle of ``scenario`` and write ``out/summary.json``; return the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    run = Run(scenario)
    for _ in range(scenario.total_cycles):
        outcome = run.cycle()
        if on_cycle is not None:
            on_cycle(outcome)
    summary = run.summary()
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _with_nan(chunk: ActionChunk) -> ActionChunk:
    actions = np.array(chunk.actions, dtype=np.float64)
    actions[actions.shape[0] // 2:, 1] = np.nan
    return ActionChunk(actions, chunk.t_obs_ns, chunk.dt_ns, chunk.uncertainty)
