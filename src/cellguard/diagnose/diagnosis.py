"""The diagnosis of a record: baseline, drift alarms, last good versus faulted, causes, asymmetry.

A pure function of (cycles, events, context): it reads no ground truth and no files, so it
gives the same answer from a run in memory and from a record read back months later.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

from cellguard.control.events import ROUTINE_EVENTS, EventKind
from cellguard.diagnose.asymmetry import Asymmetry, asymmetry_onset, held_before, mirror_map, mirrored_asymmetry
from cellguard.diagnose.baseline import OWN_SOURCE, Baseline, TooFewCycles
from cellguard.diagnose.cause import (CONCURRENT, MATERIAL, Finding, intermittent_findings, name_causes, told,
                                     tracking_rises)
from cellguard.diagnose.compare import FeatureChange, changes, last_good_and_faulted
from cellguard.diagnose.cycles import Cycle, as_cycles
from cellguard.diagnose.drift import DriftAlarm, DriftConfig, DriftResult, detect_drift
from cellguard.diagnose.feature_kinds import member_of
from cellguard.diagnose.intermittent import find_intermittent, without_outliers
from cellguard.diagnose.process import ProcessNote, condition, declared
from cellguard.diagnose.recovery import (advice, advice_lines, attempts_of, fixes, policy_cycles, recovery_finding,
                                        with_running_again, without_recovery_motion)
from cellguard.diagnose.residual import residual_alarms, with_residual
from cellguard.diagnose.run_end import CUT_SHORT, RunEnd, cut_short, run_end, with_stop_cause
from cellguard.diagnose.slip_gone import SlipGone, centre_shift, read_from_zero, slip_gone
from cellguard.embodiment.profile import SymmetryPair
from cellguard.errors import RecordError
from cellguard.robot.recovery.outcome import RecoveryOutcome


# why a cycle has no tick features (its joint currents, tracking, friction: NaN, so compared on none of them)
NO_TICK_FEATURES = ("the tick buffer filled (cycle_buffer_full: no memory for more of a cycle's ticks): joint "
                    "currents, tracking and friction not compared there; the record holds every tick")
# why a fault present in the acceptance cycles of the record has no last good cycle
FROM_START = ("present from the first cycle recorded: no good cycle in this record; diagnose against another "
              "record's acceptance")


@dataclass(frozen=True)
class Diagnosis:
    """Everything ``cellguard diagnose`` prints and the report draws."""

    cycles: tuple[Cycle, ...]
    baseline: Baseline
    drift: DriftResult
    findings: tuple[Finding, ...]
    changes: tuple[FeatureChange, ...]
    last_good_cycle: int | None
    first_faulted_cycle: int | None
    safety_events: tuple[dict, ...]
    asymmetry: Asymmetry | None
    context: Mapping = field(default_factory=dict)
    process: tuple[ProcessNote, ...] = ()  # what was done with each declared process change
    recoveries: tuple[dict, ...] = ()  # every recovery attempt, with its cycle and outcome
    fixes: tuple[dict, ...] = ()  # per finding and behaviour: cycles it ran in and fixed (for the site's history)
    advice: tuple[dict, ...] = ()  # per finding: what fixed the same cause before at this site
    unwatched: tuple[int, ...] = ()  # watched cycles of another load: their joint currents and tracking unwatched
    no_tick_features: tuple[int, ...] = ()  # cycles whose tick buffer filled: compared on none of their tick features
    run_end: RunEnd | None = None  # the event that ended the run (a stop, the operator's, a lost process), if any
    cut_short: tuple[int, ...] = ()  # cycles the run's end cut short: left out of the monitors
    from_start: str | None = None  # the first finding, there from the first cycle recorded (``FROM_START``)
    slip_gone: SlipGone | None = None  # a slip the baseline holds, gone in the watched cycles: no fault of this run

    def to_dict(self) -> dict:
        """The JSON of DESIGN.md (``cycles`` ... ``safety_events``) plus detail fields."""
        return {
            "cycles": len(self.cycles),
            "baseline_cycles": self.baseline.n,
            "last_good_cycle": self.last_good_cycle,
            "first_faulted_cycle": self.first_faulted_cycle,
            "drift_alarms": [a.to_dict() for a in self.drift.alarms],
            "findings": [f.to_dict() for f in self.findings],
            "baseline_trends": dict(self.baseline.trends),
            "baseline_steps": None if self.baseline.steps is None else dict(self.baseline.steps),
            "load_features_unwatched_cycles": list(self.unwatched),
            "cycles_without_tick_features": {"count": len(self.no_tick_features), "cycles": list(self.no_tick_features),
                                             "why": NO_TICK_FEATURES if self.no_tick_features else None},
            "safety_events": list(self.safety_events),
            "run_end": self.run_end.to_dict() if self.run_end is not None else None,
            "cut_short_cycles": {"cycles": list(self.cut_short), "why": CUT_SHORT if self.cut_short else None},
            "present_from_start": self.from_start,
            "baseline_slip_gone": self.slip_gone.to_dict() if self.slip_gone is not None else None,
            "changes": [c.to_dict() for c in self.changes],
            "asymmetry": self.asymmetry.to_dict() if self.asymmetry is not None else None,
            "process": [n.to_dict() for n in self.process],
            "recoveries": list(self.recoveries),
            "fixes": list(self.fixes),
            "advice": list(self.advice),
            "record": record_facts(self.context),
            "monitor": {"cusum_k": self.drift.k, "cusum_h": round(self.drift.threshold, 3),
                        "pooled_k": self.drift.pooled_k, "pooled_h": round(self.drift.pooled_threshold, 3),
                        "mewma_limit": round(self.drift.mewma_threshold, 2), "features": len(self.drift.names),
                        "set_arl_cycles": self.drift.set_arl, "baseline_source": self.baseline.source},
        }


def diagnose(rows: Iterable[object], events: Iterable[object] = (), context: Mapping | None = None,
             baseline: Baseline | None = None, symmetry: Sequence[SymmetryPair] = (),
             config: DriftConfig = DriftConfig(), history: Sequence[Mapping] = (),
             reference: Sequence[tuple[int, RecoveryOutcome]] | None = None) -> Diagnosis:
    """Diagnose a run from its cycles (any source, see ``as_cycle``), events and context.

    ``baseline`` defaults to the acceptance cycles of the same run; pass one to compare with a
    separate acceptance record (its ``source`` not ``OWN_SOURCE``): then every cycle of this run is
    watched, its acceptance cycles too (a fault that began in them was dated at its first production
    cycle), and its recoveries are judged against ``reference``, that record's acceptance attempts
    (``recovery.acceptance_attempts``; this run's own were another acceptance than the baseline's; None: this run's
    own, its production cycles judged, as without a baseline given).
    ``symmetry`` enables the mirrored-motion comparison. ``history``: what fixed each cause
    in this site's other records (rows of ``recovery.fixes``), for advice.
    """
    rows = list(rows)
    cycles = as_cycles(rows)
    evs = [_event_dict(e) for e in events]
    spans = _cycle_spans(cycles)
    for e in evs:
        if not e.pop(_STAMPED, False) and e.get("cycle") is None:  # a record's own "in no cycle" stands
            e["cycle"] = _cycle_of(e["t_ns"], spans)
    end, cut = run_end(evs), cut_short(cycles, evs)
    whole = [c for c in cycles if c.index not in cut]
    if not any(c.phase != "acceptance" for c in whole):  # the run ended in its first production cycle: watched as
        whole, cut = list(cycles), ()  # before, part of a cycle (left out, the record could not be diagnosed at all)
    other = None  # the recovery attempts of the baseline's acceptance where that is another record's
    if baseline is None:
        acceptance = [c for c in whole if c.phase == "acceptance"]
        baseline = Baseline.from_cycles(policy_cycles(acceptance))
        watched = [c for c in whole if c.phase != "acceptance"]
    elif baseline.source != OWN_SOURCE:  # from another record: this one's acceptance cycles are watched too
        watched, other = list(whole), reference
    else:
        watched = [c for c in whole if c.phase != "acceptance"] or list(whole)
    if not watched:
        ended = f" (cycle {', '.join(map(str, cut))} {CUT_SHORT}, by {end.words()})" if cut and end else ""
        raise TooFewCycles(f"diagnose: the record has no production cycles to compare with the baseline{ended}")
    z, notes = condition(baseline, watched, baseline.residuals(watched), declared(context))
    z = without_recovery_motion(baseline.names, watched, z)
    gone = slip_gone(baseline, watched, z)
    z, shift = read_from_zero(baseline, watched, z, gone), centre_shift(baseline, watched, gone)
    found = find_intermittent(baseline.names, watched, z)
    drift = detect_drift(baseline, watched, config, residuals=without_outliers(baseline.names, watched, z, found))
    rejected = _rejections([*watched, *(c for c in cycles if c.index in cut)], evs)  # events tell of a cut cycle
    findings = intermittent_findings(baseline, watched, z, found,
                                     name_causes(baseline, watched, drift.z, drift.alarms, rejected, shift), shift)
    findings, gone = _slipped_again(findings, gone)
    findings = with_residual(findings, residual_alarms(rows))  # the calibration's residual monitor, if it ran
    findings = with_stop_cause(findings, end, cycles, baseline, evs)
    asym = mirrored_asymmetry(watched, symmetry)
    if asym is not None and asym.significant:
        findings = _fold_compensation(findings, asym, symmetry)
        if not any(set(f.joints) & set(asym.joints) for f in findings):
            began = asymmetry_onset(whole, asym, symmetry, watched[0].index)
            # in the cycles before the watched ones (the acceptance) too: there from the first cycle recorded
            held = began == watched[0].index and held_before(whole, asym, symmetry, began)
            findings = _with_asymmetry(findings, asym, began, FROM_START if held else None)
    attempts = attempts_of(rows, evs)  # evs: for the cycle a killed run left with no row
    late = recovery_finding(cycles, attempts, other)
    findings += [late] if late is not None else []
    findings = _weak_side_joints(findings, symmetry, tracking_rises(baseline, watched, drift.z))
    findings = sorted(_carried_by_the_others(_on_legs(findings, symmetry)), key=lambda f: (f.cycle, f.cause))
    own = fixes(findings, cycles, attempts)
    advised = advice(findings, history)
    lines = advice_lines(advised)
    findings = [replace(f, evidence=f.evidence + (lines[f.cause, f.cycle],)) if (f.cause, f.cycle) in lines else f
                for f in with_running_again(findings, own)]
    findings = _on_a_trend(findings, baseline)
    first = findings[0].cycle if findings else None
    from_start = f"{findings[0].cause} from cycle {first}: {FROM_START}" if first is not None and \
        FROM_START in findings[0].evidence else None
    good, faulted = last_good_and_faulted(cycles, first)
    good = None if from_start else good
    return Diagnosis(
        cycles=tuple(cycles), baseline=baseline, drift=drift, findings=tuple(findings),
        changes=tuple(changes(baseline, drift.alarms, good, faulted, watched, _not_before(findings, first))),
        last_good_cycle=good.index if good else None, first_faulted_cycle=faulted.index if faulted else None,
        safety_events=tuple(_safety(e) for e in evs if e.get("kind") not in ROUTINE_EVENTS),
        asymmetry=asym, context=dict(context or {}), process=notes,
        recoveries=tuple({"cycle": c, **o.to_dict()} for c, o in attempts), fixes=tuple(own), advice=tuple(advised),
        unwatched=tuple(baseline.other_load(watched)), no_tick_features=_without_tick_features(cycles, evs),
        run_end=end, cut_short=cut, from_start=from_start, slip_gone=gone)



def _slipped_again(findings: list[Finding], gone: SlipGone | None) -> tuple[list[Finding], SlipGone | None]:
    """A slip found from the cycle the baseline's slip was gone on: no "the slip is gone" note beside it; its
    evidence says its change is read from 0, not from the baseline's slipped tool."""
    if gone is None or not any(f.cause == "tool_slip" and f.cycle >= gone.cycle for f in findings):
        return findings, gone
    return [told(f, (gone.read_words(),)) if f.cause == "tool_slip" and f.cycle >= gone.cycle else f
            for f in findings], None

def record_facts(context: Mapping) -> dict:
    """What dates and names the diagnosed run, from its context: record id, start (UTC, ISO 8601) and embodiment
    profile version; None for what an older record's context does not hold."""
    emb = context.get("embodiment")
    return {"record_id": context.get("record_id"), "start_utc": context.get("start_utc"),
            "profile_version": emb.get("version") if isinstance(emb, Mapping) else None}


def unwatched_words(unwatched: Sequence[int], cycles: Sequence[Cycle] = ()) -> str:
    """The notice for watched cycles whose load-dependent features went unwatched, in one line. Each is named by its
    phase among ``cycles`` (the diagnosed ones): against another record's acceptance this record's acceptance cycles
    are watched too, and one was called a production cycle."""
    return (f"joint currents and tracking unwatched on {_by_phase(unwatched, cycles)} cycle(s) that carried another "
            f"load than the baseline's acceptance (no part grasped): a joint fault there is not seen (cycles "
            f"{_shown(unwatched)})")


def _by_phase(indices: Sequence[int], cycles: Sequence[Cycle]) -> str:
    """How many of ``indices`` are acceptance and production cycles among ``cycles``: ``2 production``."""
    acceptance = {c.index for c in cycles if c.phase == "acceptance"}
    count = Counter("acceptance" if c in acceptance else "production" for c in indices)
    return " and ".join(f"{n} {phase}" for phase, n in sorted(count.items()))


def _shown(indices: Sequence[int]) -> str:
    """Cycle indices in a line: the first 8, then ``...``."""
    return ", ".join(str(c) for c in indices[:8]) + (" ..." if len(indices) > 8 else "")


def no_tick_words(no_tick: Sequence[int], cycles: Sequence[Cycle] = ()) -> str:
    """The notice for cycles with no tick features, in one line, each counted by its phase among ``cycles``: the
    comparison left them out of its joint features, and a shorter comparison is no healthier one."""
    return f"{_by_phase(no_tick, cycles)} cycle(s) without tick features: {NO_TICK_FEATURES} (cycles {_shown(no_tick)})"


def trend_words(baseline: Baseline, names: Sequence[str]) -> str:
    """How ``names`` (features not steady in acceptance) moved over the acceptance cycles, in words: a step with
    the cycle it began at (an event to look for there), else a trend; neither where the baseline does not tell
    (one written before steps were)."""
    steps = baseline.steps

    def change(n: str) -> str:
        m, d = baseline.median(n), baseline.trends[n]
        by = f"{d / abs(m) * 100:+.1f} %" if m else f"{d:+.3g}"
        if steps is None:
            return f"{n} {by}"
        return f"{n} stepped {by} at cycle {steps[n]}" if n in steps else f"{n} trended {by}"
    return (f"{', '.join(change(n) for n in names[:4])}{' ...' if len(names) > 4 else ''} over acceptance "
            f"cycles {baseline.cycles[0]} to {baseline.cycles[1]}")


def _on_a_trend(findings: list[Finding], baseline: Baseline) -> list[Finding]:
    """Findings in features that were not steady in acceptance, told so: the baseline holds part of
    the change (it reads smaller than it is), and it may have begun before the first production cycle."""
    out = []
    for f in findings:
        moved = sorted(set(f.signals) & set(baseline.trends))
        out.append(told(f, (f"the acceptance cycles were not steady ({trend_words(baseline, moved)}): the baseline "
                            "holds part of this change, which may have begun before production",)) if moved else f)
    return out


def _not_before(findings: Sequence[Finding], first: int | None) -> Callable[[DriftAlarm], int]:
    """When an alarmed feature began to change, as the change list dates it: its CUSUM's change point, never before
    the onset of the finding that names it (the first faulted cycle where none does). A noise dip before a step
    starts a CUSUM early: a fixture shift at 14 listed its fiducial from 11, a cycle the page calls good; a fit of
    each feature's own step dated a ramp at its alarm, after the finding."""
    since: dict[str, int] = {}
    for f in findings:
        for signal in f.signals:
            since[signal] = min(since.get(signal, f.cycle), f.cycle)
    return lambda a: max(a.onset, since.get(a.signal, a.onset if first is None else first))


def _legs(pairs: Sequence[SymmetryPair]) -> list[str]:
    """The legs a symmetry map implies (``fl_hip``/``fr_hip`` -> ``fl``, ``fr``); none on a robot without legs."""
    return sorted({leg for left, right in mirror_map(pairs).items() if left not in {p.left for p in pairs}
                   for leg in (left, right)})


def _on_legs(findings: list[Finding], pairs: Sequence[SymmetryPair]) -> list[Finding]:
    """On a legged robot (its symmetry map implies legs), say which legs a joint finding is on, and
    drop a foot contact finding on a leg whose joints already explain it."""
    legs = _legs(pairs)
    if not legs:
        return findings
    out = []
    for f in findings:
        on = tuple(sorted({leg for j in f.joints for leg in legs if j.startswith(f"{leg}_")}))
        out.append(replace(f, legs=on, evidence=(f"on leg {', '.join(on)}",) + f.evidence) if on else f)
    explained = {leg for f in out if f.joints for leg in f.legs}
    return [f for f in out if not (f.cause == "foot_contact" and set(f.legs) <= explained)]


def _weak_side_joints(findings: list[Finding], pairs: Sequence[SymmetryPair],
                      rise: Callable[[str, int], float]) -> list[Finding]:
    """On a legged robot, a joint of a friction finding begun with a servo finding (within ``CONCURRENT``), on that
    finding's side of the symmetry map, whose tracking error rose (``rise``) at least as much as the least of its
    joints' did, is weak too and moves into it: a weak drive on the side that now carries more of the body raises its
    current with its error, and equal rises read as friction, then as compensation (the quadruped scenario's
    fl_abduction, +36 % each, the largest change of the six weakened joints)."""
    if not _legs(pairs):
        return findings
    sides = ({p.left for p in pairs}, {p.right for p in pairs})
    out: list[Finding | None] = list(findings)
    for i, head in enumerate(findings):
        side = next((s for s in sides if head.cause == "servo" and head.joints and set(head.joints) <= s), set())
        least = min((rise(j, head.cycle) for j in head.joints), default=float("nan"))
        if not side or not least >= MATERIAL:
            continue
        for k, f in enumerate(out):
            if f is None or f.cause != "friction" or abs(f.cycle - head.cycle) > CONCURRENT:
                continue
            weak = [j for j in f.joints if j in side and rise(j, f.cycle) >= least]
            if weak:
                out[i], out[k] = _moved_in(out[i], f, weak, least), _moved_out(f, weak)
    return [f for f in out if f is not None]


def _moved_in(head: Finding, f: Finding, weak: list[str], least: float) -> Finding:
    """Servo finding ``head`` with joints ``weak`` of ``f``: their lines beside its own joints', and why."""
    joints = tuple(sorted(set(head.joints) | set(weak)))
    lines = {j: e for e in head.evidence + f.evidence for j in joints if e.startswith(f"{j}: ")}
    rest = tuple(e for e in head.evidence if e not in lines.values())
    why = (f"{', '.join(weak)} on the same side: tracking error rose at least as much as the weak joints' "
           f"(+{least * 100:.1f} %), so the drive weakened too; the current rose with it, which read as friction")
    return replace(head, joints=joints, evidence=tuple(lines[j] for j in joints if j in lines) + (why,) + rest,
                   signals=tuple(sorted(set(head.signals) | {s for s in f.signals if member_of(s) in weak})))


def _moved_out(f: Finding, weak: list[str]) -> Finding | None:
    """Finding ``f`` without joints ``weak`` (their lines and signals); None where it had no other joint."""
    joints = tuple(j for j in f.joints if j not in weak)
    if not joints:
        return None
    own = tuple(f"{j}: " for j in weak)
    return replace(f, joints=joints, evidence=tuple(e for e in f.evidence if not e.startswith(own)),
                   signals=tuple(s for s in f.signals if member_of(s) not in weak))


def _carried_by_the_others(findings: list[Finding]) -> list[Finding]:
    """A leg whose servo weakened carries less of the body: the other legs take its share (their
    current rises, which reads as friction), the weak leg's other joints make up for the weak one,
    and every foot's timing shifts. Friction and foot contact findings that start with a servo
    finding on a leg, on any legs, are folded into it."""
    weak = [f for f in findings if f.cause == "servo" and f.legs]
    extra: dict[int, list[str]] = {}
    out = []
    for f in findings:
        head = next((w for w in weak if f.cause in ("friction", "foot_contact") and abs(f.cycle - w.cycle) <= CONCURRENT
                     and f.legs and not set(f.joints) & set(w.joints)), None)
        if head is None:
            out.append(f)
            continue
        what = "take its share of the body" if f.cause == "friction" else "steps differently with it"
        own = [j for j in f.joints for leg in head.legs if j.startswith(f"{leg}_")]
        what += f", {', '.join(own)} on the weak leg itself among them" if own else ""
        data = "; ".join(e for e in f.evidence if e.endswith("vs baseline") and not e.startswith("also "))
        extra.setdefault(id(head), []).append(f"leg {', '.join(f.legs)} {what} ({data})")
    return [replace(f, evidence=f.evidence[:-1] + tuple(extra[id(f)]) + f.evidence[-1:]) if id(f) in extra else f
            for f in out]


def _fold_compensation(findings: list[Finding], asym: Asymmetry, pairs: Sequence[SymmetryPair]) -> list[Finding]:
    """Joint findings confined to the healthy side, starting with one on the faulty side, are the
    healthy side compensating: fold them into that finding as evidence."""
    healthy = {p.right for p in pairs} if asym.side == "left" else {p.left for p in pairs}
    main = [f for f in findings if set(f.joints) & set(asym.joints)]
    if not main:
        return findings
    folded = [f for f in findings if f.joints and set(f.joints) <= healthy
              and any(abs(f.cycle - m.cycle) <= 2 for m in main)]
    if not folded:
        return findings
    head = main[0]
    note = (f"the {'right' if asym.side == 'left' else 'left'} side compensates "
            f"({', '.join(j for f in folded for j in f.joints)}); mirrored motions differ on the {asym.side} side",)
    merged = Finding(head.cause, head.cycle, head.confidence, head.evidence + note, head.signals, head.joints)
    return [merged if f is head else f for f in findings if f not in folded]


def _with_asymmetry(findings: list[Finding], asym: Asymmetry, began: int, since: str | None = None) -> list[Finding]:
    """An asymmetry no joint finding explains, from cycle ``began``: a late policy that began with it
    (within ``CONCURRENT`` cycles; one long before does not) explains it (a stale plan on a turning robot tells its sides apart), so it is told in
    that finding's evidence; else it is a finding of its own, with ``since`` (``FROM_START``) where it was there before
    ``began``, the first watched cycle."""
    late = next((f for f in findings if f.cause == "policy_latency" and abs(f.cycle - began) <= CONCURRENT), None)
    if late is None:
        own = _asymmetry_finding(asym, began)
        return findings + [told(own, (since,)) if since else own]
    note = (f"mirrored motions differ {asym.where} from cycle {began} "
            f"({', '.join(asym.what[:5])}): the late chunks, not a joint",)
    return [told(f, note, [d.feature for d in asym.significant]) if f is late else f for f in findings]


def _asymmetry_finding(asym: Asymmetry, cycle: int) -> Finding:
    """A side that tracks worse than its mirror with little extra current reads as a servo fault."""
    sig = asym.significant
    trk = [abs(d.relative) for d in sig if d.feature.startswith("tracking_")]
    cur = [abs(d.relative) for d in sig if d.feature.startswith("current_")]
    t, c = (max(trk) if trk else 0.0), (max(cur) if cur else 0.0)
    cause = "servo" if t >= c and trk else "friction" if cur else "unknown"
    share = max(t, c) / (t + c) if t + c > 0 else 0.5
    conf = float(min(0.95, 0.5 + 0.9 * (share - 0.5))) if cause != "unknown" else 0.3
    return Finding(cause, cycle, conf, (f"mirrored motions differ {asym.where}",) + asym.evidence[1:5],
                   tuple(sorted({d.feature for d in sig})), asym.joints)


_STAMPED = "_stamped"  # an event read from a record, whose recorder placed it in a cycle or in none


def _event_dict(e: object) -> dict:
    """``e`` as a dict. A record's event keeps its cycle, None included: the recorder knows whether it came after
    the cycle's end marker, which time alone cannot tell at the end's own time (the retreat's first event, a stop
    there); events given as mappings without one (a summary's) are placed by time."""
    d = dict(e) if isinstance(e, Mapping) else {k: v for k, v in vars(e).items() if v is not None}
    if not isinstance(e, Mapping) and hasattr(e, "cycle"):
        d[_STAMPED] = True
    if "t_ns" not in d:
        raise RecordError(f"event: needs 't_ns', got keys {sorted(d)}")
    return d


def _cycle_spans(cycles: Sequence[Cycle]) -> list[tuple[int, int, int]]:
    """(start, end, index) per cycle; from the record's stamps, else from back-to-back cycle times."""
    spans, t = [], 0
    for c in cycles:
        if c.t_start_ns is not None and c.t_end_ns is not None:
            spans.append((int(c.t_start_ns), int(c.t_end_ns), c.index))
            t = int(c.t_end_ns)
        else:
            end = t + round(c.features.get("cycle_time_s", 0.0) * 1e9)
            spans.append((t, end, c.index))
            t = end
    return spans


def _cycle_of(t_ns: int, spans: list[tuple[int, int, int]]) -> int | None:
    for start, end, index in spans:
        if start <= t_ns <= end:
            return index
    return None


def _without_tick_features(cycles: Sequence[Cycle], events: list[dict]) -> tuple[int, ...]:
    """The cycles whose tick buffer filled (a ``cycle_buffer_full`` event in them): their tick features are NaN,
    and the comparison silently left them out."""
    indices = {c.index for c in cycles}
    return tuple(sorted({e["cycle"] for e in events
                         if e.get("kind") == EventKind.CYCLE_BUFFER_FULL and e.get("cycle") in indices}))


def _rejections(watched: Sequence[Cycle], events: list[dict]) -> list[tuple[int, str]]:
    """(cycle, reason) of every rejected chunk in the watched cycles, from events or features."""
    indices = {c.index for c in watched}
    out = [(e["cycle"], e.get("reason", "")) for e in events
           if e.get("kind") == EventKind.CHUNK_REJECTED and e.get("cycle") in indices]
    if not out:
        out = [(c.index, "chunk rejected") for c in watched if c.features.get("chunks_rejected", 0) > 0]
    return out


def _safety(e: dict) -> dict:
    out = {"t": round(e["t_ns"] * 1e-9, 3), "kind": e.get("kind"), "cycle": e.get("cycle")}
    for k in ("category", "joint", "asked", "sent", "reason"):
        if e.get(k) is not None:
            out[k] = e[k]
    return out
