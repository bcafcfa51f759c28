"""The end of a run in its record: the event that ended it, the cycle it cut short, the cause of a stop.

A cycle an ``ends_run`` event falls in was cut short: its features are those of a part of a cycle, not of a
production cycle, so the monitors leave it out (one such cycle raised the multivariate alarm alone). The stop
that ended a run is the events' business: a policy whose chunks all came stale until it was lost is
``policy_latency``, read from those events and the latency the cut cycle's chunks had, though one cycle is
too few for the drift monitors to alarm on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cellguard.control.events import EventKind
from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cause import Finding, told
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.intermittent import OUTLIER

# the operator's stop, a lost process (killed, out of memory): the operator's and the host's, no fault of the cell
NOT_THE_CELL = (EventKind.OPERATOR_STOP, EventKind.RUN_PROCESS_LOST)
# how the guard refused a policy's answers: a chunk too late (stale), a chunk it could not follow (rejected), a call
# that failed; the watchdog stops for want of a chunk whatever the reason (every loss after a first chunk has one)
REFUSED = (EventKind.CHUNK_STALE, EventKind.CHUNK_REJECTED, EventKind.INFERENCE_FAILED)
CUT_SHORT = "cut short by the run's end: left out of the monitors"


@dataclass(frozen=True)
class RunEnd:
    """The event that ended the run (``EventKind.ends_run``): its kind, cycle, stop category and reason."""

    kind: str
    cycle: int | None
    category: int | None
    reason: str
    t: float  # [s] the record's clock

    @property
    def needs_cause(self) -> bool:
        """Whether a fault of the cell (its policy, robot, guard or record) may have ended the run: a cause to find."""
        return self.kind not in NOT_THE_CELL

    def words(self) -> str:
        cycle = "" if self.cycle is None else f" in cycle {self.cycle}"
        category = "" if self.category is None else f", category {self.category}"
        return f"{self.kind}{cycle}{category}: {self.reason}"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "cycle": self.cycle, "category": self.category, "reason": self.reason,
                "t": self.t, "needs_cause": self.needs_cause}


def _ends_run(kind: object) -> bool:
    return kind in EventKind.__members__.values() and EventKind(kind).ends_run


def run_end(events: Sequence[dict]) -> RunEnd | None:
    """The first ``ends_run`` event of ``events`` (dicts with their cycle), None where the run ended of itself. One
    after it (a Ctrl-C during the retreat that followed a lost policy) is no end of the run: taken as its end, the
    operator's stop hid the loss, "no fault found"."""
    ends = [e for e in events if _ends_run(e.get("kind"))]
    if not ends:
        return None
    e = min(ends, key=lambda e: e["t_ns"])
    return RunEnd(str(e["kind"]), e.get("cycle"), e.get("category"), str(e.get("reason", "")),
                  round(e["t_ns"] * 1e-9, 3))


def cut_short(cycles: Sequence[Cycle], events: Sequence[dict]) -> tuple[int, ...]:
    """The cycles of ``cycles`` an ``ends_run`` event falls in: cut short, not completed."""
    indices = {c.index for c in cycles}
    return tuple(sorted({e["cycle"] for e in events if _ends_run(e.get("kind")) and e.get("cycle") in indices}))


def with_stop_cause(findings: list[Finding], end: RunEnd | None, cycles: Sequence[Cycle], baseline: Baseline,
                    events: Sequence[dict]) -> list[Finding]:
    """``findings`` with the cause of a lost policy that ended the run: one whose chunks came stale (or whose cut
    cycle's latency is an outlier, ``OUTLIER`` scales over the baseline) is ``policy_latency`` from that cycle,
    told in a latency finding already begun by then, else a finding of its own. Other ends are left as found (a
    policy lost to rejected chunks is ``policy_output``'s, from the events)."""
    if end is None or end.kind != EventKind.POLICY_LOST or end.cycle is None:
        return findings
    mine = [e for e in events if e.get("cycle") == end.cycle]
    refused = [e for e in mine if e.get("kind") in REFUSED]
    if refused and refused[-1].get("kind") != EventKind.CHUNK_STALE:  # lost to rejected chunks or failed calls:
        return findings  # policy_output's, or the server's (a NaN in every chunk read as latency: the watchdog)
    cut = next((c for c in cycles if c.index == end.cycle), None)
    latency = _latency_words(cut, baseline)
    stale = len(refused)
    if not stale and latency is None:
        return findings
    evidence = ((latency,) if latency else ()) + (
        (f"{stale} chunk(s) came stale in cycle {end.cycle} (every step past before it arrived)",) if stale else ()
    ) + tuple(f"{e['kind']}: {e.get('reason', '')}" for e in mine if e.get("kind") == EventKind.WATCHDOG_STOP) + (
        f"the policy was lost in cycle {end.cycle} ({end.kind}, the run's end): its chunks came too late to follow",)
    begun = next((f for f in findings if f.cause == "policy_latency" and f.cycle <= end.cycle), None)
    if begun is not None:
        return [told(f, evidence) if f is begun else f for f in findings]
    stop = Finding("policy_latency", end.cycle, 0.9, evidence + (
        "late chunks answer old observations: the guard stopped the robot rather than follow a stale plan",),
        ("latency_mean_ms", "stale_chunks"))
    return sorted([*findings, stop], key=lambda f: (f.cycle, f.cause))


def _latency_words(cut: Cycle | None, baseline: Baseline) -> str | None:
    """The cut cycle's chunk latency against the baseline's, in words, where it is an outlier; else None."""
    name = "latency_mean_ms"
    if cut is None or name not in cut.features or name not in baseline.names:
        return None
    base, scale, value = baseline.median(name), baseline.scale(name), cut.features[name]
    if not (value - base) / scale >= OUTLIER:
        return None
    return f"policy latency {value:.0f} ms per chunk in cycle {cut.index} vs {base:.0f} ms at acceptance"


def explained(findings: Sequence[Finding], end: RunEnd | None) -> bool:
    """Whether the run ended of itself, not by its cell (``NOT_THE_CELL``), or in a stop a finding begun by then
    may explain."""
    if end is None or not end.needs_cause:
        return True
    return any(end.cycle is None or f.cycle <= end.cycle for f in findings)
