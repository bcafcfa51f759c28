"""Probable cause: the pattern of what changed, read the way a technician reads it.

Rules from the physics of the cell, not a model of the injected faults (the diagnosis never
sees them). Each alarmed feature belongs to a family; each family with alarms is one
candidate finding, classified from the size and sign of its changes over the faulted cycles:

- geometry (camera-seen part and fixture, grasp pose, part-to-tool offset at grasp): the
  real part position at grasp is the grasp pose plus the offset. If the camera saw the part
  move (its readings alarmed) and the part really moved as far, the fixture moved; if the
  camera saw it move and it did not, the camera moved; if the camera saw nothing and the part
  sat off the tool with the joints' grasp pose unchanged, the tool slipped on its flange. A grasp
  that moved with the part where it really sat (pose plus offset unchanged) is where the tool
  closed: a concurrent change in how the arm moves (latency, a joint) explains it. A second geometry step
  after the first (alarms that began more than ``CONCURRENT`` cycles later, where the geometry stepped
  again) is a finding of its own, read from the level the first left: a camera that moved after the
  fixture sees the part back toward its acceptance place, which no monitor alarms on.
- one joint (current, tracking error): friction raises the current the joint needs more than
  its tracking error; a weaker servo gain raises the tracking error more than the current. On a
  loaded joint friction hardly moves the current's RMS (it adds on one stroke, subtracts on the
  other): where current and tracking error moved under ``QUIET``, a rise of the joint's friction
  torque (the drive's work over its travel) names friction. On a robot that does not stand on
  the ground (no gait features) the friction torque weighs in whenever it alarmed: a position
  servo holds more torque through a larger error, so friction raises its tracking error about
  as much as its current, while a weaker gain raises the tracking error and leaves the work over
  the travel where it was. Not on a leg where current and tracking error moved more: there the
  ground's share of that work shifts with the gait. The rise that names the cause must itself
  reach ``MATERIAL``: a joint whose current fell 3 % while its error rose 0.3 % names no weaker servo.
  The joints of an arm are coupled: a joint that lags more moves the others' loads a little. A
  joint whose change is under ``COUPLED`` of a joint's that changed no later is that joint's
  consequence, told in its evidence, not a second cause; unless its tracking error grew with no
  more current (a coupled joint's change reaches it as a load, which its servo answers with current),
  or, on an arm, more than its current under a friction lead (friction keeps the lead's motion), or, on
  an arm, its own friction torque rose (its drive does more work over its own travel).
  Where the camera saw the part move and the grasp pose followed it, the arm moves to another pick
  point: a joint change under ``PATH_PER_MM`` of each millimetre the grasp pose moved, begun with it, is its
  new path's, told in the geometry finding; a larger one is its drive's, named at a confidence lowered for
  the share the new path may hold.
- policy timing (latency, stale chunks) and policy output (rejected chunks) speak for
  themselves; joint changes, and the gait of legs, that start with a latency change are its
  consequence (a joint change that comes on some cycles only is dated by the first of them).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from cellguard.diagnose.baseline import MIN_CYCLES, Baseline, feature_matrix
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.drift import DriftAlarm
from cellguard.diagnose.feature_kinds import kind_of, member_of
from cellguard.diagnose.intermittent import AT_ZERO

CAUSES = ("fixture_shift", "friction", "servo", "camera_shift", "tool_slip", "policy_latency", "policy_output",
          "unknown", "load_change", "part_misplaced", "foot_contact", "recovery")
SIGNIFICANT_MM = 0.3  # [mm] a geometric change smaller than this is noise at this camera
CONCURRENT = 2  # [cycles] changes this close together are one episode
UNCHANGED_Z = 3.0  # |median residual| below this, in baseline scales, reads as "unchanged"
BACK = 1.0  # [scales] a change whose features read under this (median) on the cycles after it has ended
MATERIAL = 0.01  # a joint whose current and tracking error moved less than 1 % stays an alarm, not a cause
QUIET = 0.02  # current and tracking error both moved less: the friction torque speaks for the joint
STEP_CLIP = 8.0  # [scales] residuals clipped this far when a step is fitted (one odd cycle does not move it)
COUPLED = 0.2  # a joint's change under this share of an earlier joint's change follows from it
CARRY_ONLY = 0.5  # current while carrying rose, while not less than this share of it: the load changed
PATH_PER_MM = 0.005  # a joint's change under this per mm the grasp pose moved, from a moved pick point on, is the
# new path's: fixture and camera shifts of 2 to 4 mm in x, y and both (grasp pose 1.8 to 3.2 mm, 9 seeds) moved the
# arm's joints at most 0.45 % per mm (the elbow; 1.1 to 1.3 % for a 4 mm fixture shift), servo gain x0.85 on a joint
# 0.55 % per mm or more (shoulder_pan, tracking error +1.7 % beside a 3 mm move)


@dataclass(frozen=True)
class Finding:
    """A probable cause from ``cycle`` on, with a confidence in [0, 1] and the evidence in words."""

    cause: str
    cycle: int
    confidence: float
    evidence: tuple[str, ...]
    signals: tuple[str, ...] = ()
    joints: tuple[str, ...] = ()
    rate: float | None = None  # share of cycles hit, for an intermittent fault
    legs: tuple[str, ...] = ()  # the legs the joints belong to, on a legged robot

    def to_dict(self) -> dict:
        out = {"cause": self.cause, "cycle": self.cycle, "confidence": round(self.confidence, 2),
               "evidence": list(self.evidence), "signals": list(self.signals)}
        if self.joints:
            out["joints"] = list(self.joints)
        if self.legs:
            out["legs"] = list(self.legs)
        if self.rate is not None:
            out["rate"] = round(self.rate, 3)
            out["first_cycle"] = self.cycle
        return out


def family(signal: str) -> str:
    """The group a feature belongs to: ``geometry``, ``latency``, ``output``, ``joint:<name>`` ...
    (declared in ``feature_kinds``; per-joint families are split by joint)."""
    kind = kind_of(signal)
    return f"joint:{member_of(signal)}" if kind.family == "joint" else kind.family


class _Window:
    """Changes over the faulted cycles of one episode: median minus baseline, in units and scales."""

    def __init__(self, baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, shift: np.ndarray | None = None):
        self.baseline, self.cycles, self.z = baseline, cycles, z
        self.level: tuple[str, str] | None = None  # where changes are read from, if not the baseline: (place, why)
        centre, _ = baseline.centre_and_scale(cycles)
        # change from the motion's baseline, moved by ``shift`` (Shape of ``z``) where ``z`` reads from elsewhere
        self._d = feature_matrix(cycles, baseline.names) - centre - (0.0 if shift is None else shift)

    def delta(self, name: str, start: int, plus: Sequence[str] = (), minus: Sequence[str] = (),
              end: int | None = None) -> float:
        """Median change of ``name`` over cycles >= ``start`` (and before ``end``, a change that ended) [its unit],
        each cycle's plus those of the features ``plus`` and minus those of ``minus`` that are read (a position
        from its parts, whose noise is measured against each other's); NaN if never read."""
        if name not in self.baseline.names:
            return float("nan")
        terms = [(self.baseline.names.index(n), sign) for names, sign in (((name, *plus), 1.0), (minus, -1.0))
                 for n in names if n in self.baseline.names]
        rows = [i for i, c in enumerate(self.cycles) if start <= c.index and (end is None or c.index < end)]
        cols, signs = [j for j, _ in terms], np.array([sign for _, sign in terms])
        col = (np.where(np.isnan(self.z[np.ix_(rows, cols)]), np.nan, self._d[np.ix_(rows, cols)]) * signs).sum(axis=1)
        col = col[~np.isnan(col)]  # z is NaN at another load
        return float(np.median(col)) if len(col) else float("nan")

    def before(self, end: int) -> _Window:
        """The window over the cycles before ``end``, a later episode's start: an episode read over its own cycles."""
        return self._rows(np.array([c.index < end for c in self.cycles]))

    def from_level(self, since: int, start: int) -> _Window:
        """The window over the cycles from ``since`` on, each feature's change read from its median over cycles
        ``since`` to ``start`` (the level an earlier episode left; the baseline where it left no reading), not from
        the baseline: a second step is measured on its own (a camera that moved after the fixture moved the part
        seen back toward its acceptance place)."""
        w = self._rows(np.array([c.index >= since for c in self.cycles]))
        return w.read_from(np.array([c.index < start for c in w.cycles]), (
            f"where it sat on cycles {since} to {start - 1}",
            f"each change read from where the change from cycle {since} left it (cycles {since} to {start - 1}), "
            "not from acceptance"))

    def read_from(self, rows: np.ndarray, level: tuple[str, str]) -> _Window:
        """This window with each feature's change read from its median over the cycles ``rows`` marks (the
        baseline where they hold no reading); ``level`` says where that is, and why, in words."""
        w = self._rows(np.ones(len(self.cycles), dtype=bool))
        w.level = level
        for j in range(len(w.baseline.names)):
            read = rows & ~np.isnan(w.z[:, j])
            if read.any():
                w._d[:, j] -= np.median(w._d[read, j])
                w.z[:, j] -= np.median(w.z[read, j])
        return w

    def _rows(self, keep: np.ndarray) -> _Window:
        """The window over the cycles ``keep`` marks, its changes read as this one reads them."""
        w = _Window(self.baseline, [c for c, k in zip(self.cycles, keep) if k], self.z[keep].copy())
        w._d, w.level = self._d[keep].copy(), self.level
        return w

    def tracking(self, joint: str, start: int) -> float:
        """Relative change of ``joint``'s tracking error from cycle ``start`` on: its RMS's or peak's, the larger."""
        return _largest(self.relative(f"tracking_rms.{joint}", start), self.relative(f"tracking_max.{joint}", start))

    def zmed(self, name: str, start: int) -> float:
        d = self.delta(name, start)
        return d / self.baseline.scale(name) if np.isfinite(d) else float("nan")

    def relative(self, name: str, start: int) -> float:
        d = self.delta(name, start)
        m = self.baseline.median(name) if name in self.baseline.names else 0.0
        return d / abs(m) if np.isfinite(d) and m else float("nan")

    def step_onset(self, alarms: Sequence[DriftAlarm]) -> int:
        """The cycle a step in ``alarms``' features began: the split, between their earliest change point
        and their first alarm, that fits one step from the baseline in the mean of their residuals (signed,
        clipped at ``STEP_CLIP``) best by least squares over all cycles: before the split they read the
        baseline (residual 0), from it on their own mean. The median change point (``_onset``) where none
        can be fitted. One CUSUM's change point wanders with the noise before the step; the fit reads every
        cycle on both sides. With the baseline before the first watched cycle a step there is fitted too (a
        fault from the first production cycle on, or one present from the start of a record read against
        another run's acceptance)."""
        index, s = self._signed(alarms)
        if not len(s):
            return _onset(alarms)
        lo, hi = min(a.onset for a in alarms), min(a.cycle for a in alarms)
        fits = [(float(np.sum(s[:k] ** 2) + np.sum((s[k:] - s[k:].mean()) ** 2)), int(index[k]))
                for k in range(len(s)) if lo <= index[k] <= hi]
        return min(fits)[1] if fits else _onset(alarms)

    def first_of_some(self, alarms: Sequence[DriftAlarm], since: int) -> int | None:
        """The first cycle from ``since`` on that ``alarms``' features were off (their signed mean residual
        ``UNCHANGED_Z`` or more), where they are off on some cycles only (that mean under it on most cycles
        from their change point on): a CUSUM decays between such cycles and dates the change late.
        None for a step (off on most cycles), or where no cycle was off."""
        index, s = self._signed(alarms)
        after = s[index >= _onset(alarms)]
        if not len(after) or np.median(after) >= UNCHANGED_Z:
            return None
        off = index[(index >= since) & (s >= UNCHANGED_Z)]
        return int(off[0]) if len(off) else None

    def until(self, alarms: Sequence[DriftAlarm], start: int) -> int | None:
        """The cycle ``alarms``' change ended on: the one after the last that their features were off (signed mean
        residual ``UNCHANGED_Z`` or more) from ``start`` on, where more than ``CONCURRENT`` cycles follow it and
        read the baseline (median under ``BACK``); None while it lasts to the record's end."""
        index, s = self._signed(alarms)
        off = index[(index >= start) & (s >= UNCHANGED_Z)]
        after = index > off[-1] if len(off) else np.zeros(0, dtype=bool)
        return int(index[after][0]) if after.sum() > CONCURRENT and np.median(s[after]) < BACK else None

    def _signed(self, alarms: Sequence[DriftAlarm]) -> tuple[np.ndarray, np.ndarray]:
        """(cycle index, mean residual) over the cycles that read ``alarms``' features: each residual
        signed by its alarm's direction and clipped at ``STEP_CLIP``."""
        cols = [(self.baseline.names.index(a.signal), a.direction) for a in _distinct(alarms)
                if a.signal in self.baseline.names and a.direction]
        if not cols:
            return np.zeros(0, dtype=int), np.zeros(0)
        z = np.clip(self.z[:, [j for j, _ in cols]], -STEP_CLIP, STEP_CLIP) * np.array([d for _, d in cols])
        seen = ~np.all(np.isnan(z), axis=1)
        return np.array([c.index for c in self.cycles])[seen], np.nanmean(z[seen], axis=1)

    def xy(self, stem: str, start: int, axes: str = "xy") -> np.ndarray | None:
        """Median change of position ``stem`` along ``axes`` [mm]; None where one of them is never read."""
        v = np.array([self.delta(f"{stem}_{axis}_mm", start) for axis in axes])
        return v if np.all(np.isfinite(v)) else None


def name_causes(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, alarms: Sequence[DriftAlarm],
                rejected: Sequence[tuple[int, str]] = (), shift: np.ndarray | None = None) -> list[Finding]:
    """Findings from the drift alarms over ``cycles`` (those after the baseline), earliest first.

    ``rejected`` lists (cycle, reason) of chunks the guard refused (non-finite or malformed output). ``shift``
    (Shape of ``z``, [unit]): how far the centre ``z`` reads each feature from has moved off the baseline's (a slip
    the baseline holds, gone: ``slip_gone.centre_shift``); the changes are read from there too.
    """
    w = _Window(baseline, cycles, z, shift)
    groups: dict[str, list[DriftAlarm]] = {}
    for a in alarms:
        if a.signal != "multivariate":
            groups.setdefault(family(a.signal), []).append(a)
    findings: list[Finding] = []
    if rejected:
        first = min(c for c, _ in rejected)
        n = len({c for c, _ in rejected})
        findings.append(Finding("policy_output", first, 0.95, (
            f"the guard rejected {len(rejected)} policy chunk(s) in {n} cycle(s), first in cycle {first}: "
            f"{rejected[0][1]}", "a policy that emits non-finite or malformed actions"), ("chunks_rejected",)))
    joint_groups = {k.split(":", 1)[1]: v for k, v in groups.items() if k.startswith("joint:")}
    if any(kind_of(a.signal).unit == "ms" for a in groups.get("latency", ())):  # the policy answered later
        f = _latency(w, groups.pop("latency"))
        f, groups["gait"] = _with_late_gait(f, groups.get("gait", []))
        f, joint_groups = _with_late_joints(w, f, joint_groups)
        findings.append(f)
    groups.pop("output", None)
    outcome = groups.pop("outcome", [])
    geometry = groups.pop("geometry", [])
    grasps = [(_geometry(ew, g, o), ew, g) for ew, g, o in (_episodes(w, geometry, outcome) if geometry else [])]
    outcome = [] if geometry else outcome
    moves = [(f.cycle, _pick_move(ew, g, f.cycle)) for f, ew, g in grasps]
    joints, on_path = _joints(w, joint_groups, grounded=_grounded(baseline), new_paths=[m for m in moves if m[1]])
    findings.extend(joints)
    findings.extend(_feet(w, groups.pop("gait", [])))
    for grasp, ew, g in grasps:
        path = [r for r in on_path if abs(r[0] - grasp.cycle) <= CONCURRENT]
        named = any(abs(f.cycle - grasp.cycle) <= CONCURRENT for f in joints)
        if named or any(abs(r[8]) >= MATERIAL for r in path):  # a drive that changed with it: its figures are told
            grasp = replace(grasp, evidence=tuple(e for e in grasp.evidence if e != UNCHANGED_CURRENT))
        findings = _with_grasp(ew, _with_path(grasp, path), g, findings)
    other = _distinct([a for k, v in groups.items() if not k.startswith("joint:") for a in v] + outcome)
    if other and not findings:
        findings.append(Finding("unknown", _onset(other), 0.3, tuple(
            f"{a.signal} went {'up' if a.direction > 0 else 'down'} from cycle {a.onset} "
            f"({_fmt(w.delta(a.signal, a.onset, end=w.until([a], a.onset)))} vs baseline)" for a in other[:4]) + (
            "no pattern of a known cause",), tuple(sorted({a.signal for a in other}))))
    elif other:
        first = min(findings, key=lambda f: abs(f.cycle - _onset(other)))
        extra = tuple(f"also {a.signal} {'up' if a.direction > 0 else 'down'} "
                      f"({_fmt(w.delta(a.signal, a.onset, end=w.until([a], a.onset)))})" for a in other[:3])
        findings[findings.index(first)] = replace(first, evidence=first.evidence + extra)
    return sorted(findings, key=lambda f: (f.cycle, f.cause))


def tracking_rises(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray) -> Callable[[str, int], float]:
    """How much a joint's tracking error rose over ``cycles`` (residuals ``z``) from a cycle on, as the joint rules
    read it (``_Window.tracking``): the diagnosis weighs a joint of a weak side against the weak joints by it."""
    return _Window(baseline, cycles, z).tracking


def _onset(alarms: Sequence[DriftAlarm]) -> int:
    """The episode's start: the median change point of its alarms (robust to one early CUSUM), each monitor's first
    (one that re-armed and alarmed again on a lasting, noisy change dated a friction from 15 at 27)."""
    return int(np.median([a.onset for a in _firsts(alarms).values()]))


def _firsts(alarms: Sequence[DriftAlarm]) -> dict[tuple[str, int], DriftAlarm]:
    """Each monitor's (signal and side) first alarm: one that re-armed and alarmed again has a later change point."""
    first: dict[tuple[str, int], DriftAlarm] = {}
    for a in sorted(alarms, key=lambda a: (a.onset, a.cycle)):
        first.setdefault((a.signal, a.direction), a)
    return first


def _latency(w: _Window, alarms: list[DriftAlarm]) -> Finding:
    start = _onset(alarms)
    base = w.baseline.median("latency_mean_ms") if "latency_mean_ms" in w.baseline.names else float("nan")
    end = w.until(alarms, start)  # a latency that came and went is read over its own cycles
    d = w.delta("latency_mean_ms", start, end=end)
    stale = w.delta("stale_chunks", start, end=end)
    evidence = [f"policy latency {base + d:.0f} ms per chunk vs {base:.0f} ms at acceptance" + (
        f", on cycles {start} to {end - 1}; back to {base:.0f} ms from cycle {end}" if end is not None else "")]
    if np.isfinite(stale) and stale > 0:
        evidence.append(f"{stale:.0f} more stale chunk steps dropped per cycle")
    evidence.append("late chunks answer old observations, so the robot follows a stale plan")
    conf = 0.95 if np.isfinite(d) and d > 5.0 else 0.6
    return Finding("policy_latency", start, conf, tuple(evidence), tuple(sorted({a.signal for a in alarms})))


def _with_late_gait(late: Finding, gait: list[DriftAlarm]) -> tuple[Finding, list[DriftAlarm]]:
    """The legs whose gait timing began to change with the latency (their first alarm within
    ``CONCURRENT`` of it) step to a stale plan: told in the latency finding, not as foot contact
    findings. Returns the finding and the gait alarms of the other legs."""
    legs = _by_leg(gait)
    with_it = sorted(leg for leg, group in legs.items() if abs(min(a.onset for a in group) - late.cycle) <= CONCURRENT)
    if not with_it:
        return late, gait
    signals = sorted({a.signal for leg in with_it for a in legs[leg]})
    note = (f"also the gait of leg {', '.join(with_it)} from cycle {late.cycle} ({', '.join(signals[:4])}"
            f"{' ...' if len(signals) > 4 else ''}): the legs step to the stale plan",)
    rest = [a for a in gait if member_of(a.signal) not in with_it]
    return told(late, note, signals, before_last=True), rest


def _with_late_joints(w: _Window, late: Finding, groups: dict[str, list[DriftAlarm]]
                      ) -> tuple[Finding, dict[str, list[DriftAlarm]]]:
    """The joints whose change began with the latency (``_began_with``) follow the stale plan: told in the
    latency finding, not as joint findings. Returns the finding and the other joints' alarm groups."""
    later = {j: _rearmed(alarms, late.cycle + CONCURRENT) for j, alarms in groups.items()}
    earlier = {j: [a for a in alarms if a not in later[j]] for j, alarms in groups.items()}
    with_it = sorted(j for j, alarms in earlier.items() if alarms and _began_with(w, alarms, late.cycle))
    if not with_it:
        return late, groups
    signals = sorted({a.signal for j in with_it for a in earlier[j]})
    note = (f"also joint {', '.join(with_it)} from cycle {late.cycle} ({', '.join(signals[:4])}"
            f"{' ...' if len(signals) > 4 else ''}): they change with the stale plan (a drive that changed at the same "
            "cycle would read the same: check these joints once the latency is fixed)",)
    rest = {j: v if j not in with_it else later[j] for j, v in groups.items()}
    return told(late, note, signals, before_last=True), {j: v for j, v in rest.items() if v}


def _rearmed(alarms: Sequence[DriftAlarm], after: int) -> list[DriftAlarm]:
    """The alarms of a change that began after ``after``, once the change before it on the same features had ended:
    from the first alarm again of a signal (its monitor re-arms only once its change ended) that began after
    ``after``, those again and the first alarms of other signals that began with it or later."""
    first = _firsts(alarms)
    again = [a for a in alarms if first[a.signal, a.direction] is not a and a.onset > after]
    if not again:
        return []
    start = min(a.onset for a in again) - CONCURRENT
    again_of = {(a.signal, a.direction) for a in again}
    return [a for a in alarms if a in again or ((a.signal, a.direction) not in again_of and a.onset >= start)]


def _began_with(w: _Window, alarms: list[DriftAlarm], at: int) -> bool:
    """Whether the change ``alarms`` tell of began within ``CONCURRENT`` of cycle ``at``: by their change
    point or, where they are off on some cycles only (the motions a stale plan spoils), by the first
    of those cycles (``_Window.first_of_some``), which their CUSUM, decaying between them, dates late."""
    first = w.first_of_some(alarms, at - CONCURRENT)
    return abs(_onset(alarms) - at) <= CONCURRENT or (first is not None and first - at <= CONCURRENT)


def told(f: Finding, words: tuple[str, ...], signals=(), before_last: bool = False) -> Finding:
    """``f`` with ``words`` added to its evidence (before its closing line, with ``before_last``) and ``signals``
    to its own: another change told as this finding's consequence, not a finding of its own."""
    evidence = f.evidence[:-1] + words + f.evidence[-1:] if before_last else f.evidence + words
    return replace(f, evidence=evidence, signals=tuple(sorted(set(f.signals).union(signals))))


def _distinct(alarms: Sequence[DriftAlarm]) -> list[DriftAlarm]:
    """One alarm per signal, the earliest (a monitor that alarms again after its reset adds nothing)."""
    seen: dict[str, DriftAlarm] = {}
    for a in sorted(alarms, key=lambda a: (a.onset, a.cycle)):
        seen.setdefault(a.signal, a)
    return [a for a in alarms if seen[a.signal] is a]


def _episodes(w: _Window, geometry: list[DriftAlarm], outcome: list[DriftAlarm]
              ) -> list[tuple[_Window, list[DriftAlarm], list[DriftAlarm]]]:
    """The geometry and outcome alarms split into episodes, one geometry finding each, with the window each is read
    over: where alarms began more than ``CONCURRENT`` cycles after the geometry's onset (at their median change
    point) and geometry features stepped there from the level the episode before left (``_stepped``), that is another
    episode, read from that level, and it bounds the one before (a camera that moved after the fixture was told as
    the fixture, from a blend of both). Each episode's (geometry, outcome) alarms."""
    start = w.step_onset(geometry)
    later = [a for a in geometry + outcome if a.onset > start + CONCURRENT]
    if not later:
        return [(w, geometry, outcome)]
    nxt = _onset(later)
    level = w.from_level(start, nxt)
    stepped = _stepped(level, nxt)
    if not stepped:
        return [(w, geometry, outcome)]
    first = (w.before(nxt), [a for a in geometry if a not in later], [a for a in outcome if a not in later])
    return [first, *_episodes(level, [a for a in later if a in geometry] + stepped, [a for a in later if a in outcome])]


def _stepped(w: _Window, start: int) -> list[DriftAlarm]:
    """The geometry features whose median from ``start`` on moved ``UNCHANGED_Z`` scales and ``SIGNIFICANT_MM`` or more
    in ``w``, as alarms from ``start``: a step back toward the acceptance place raises no alarm of its own (the
    feature's monitor alarmed the other way on the first step and reads it as less of that change)."""
    moved = [(n, w.zmed(n, start)) for n in w.baseline.names if kind_of(n).family == "geometry"
             and kind_of(n).unit == "mm" and abs(w.delta(n, start)) >= SIGNIFICANT_MM]
    return [DriftAlarm(n, start, 0.0, start, int(np.sign(z))) for n, z in moved if abs(z) >= UNCHANGED_Z]


def _geometry(w: _Window, alarms: list[DriftAlarm], outcome: list[DriftAlarm]) -> Finding:
    start = w.step_onset(alarms)
    signals = tuple(sorted({a.signal for a in alarms + outcome}))
    seen_parts = [v for v in (w.xy("part_seen", start), w.xy("fixture_seen", start)) if v is not None]
    seen = np.mean(seen_parts, axis=0) if seen_parts else np.zeros(2)
    tcp = w.xy("grasp_tcp", start)
    off = w.xy("grasp_offset", start)
    tcp = np.zeros(2) if tcp is None else tcp
    off = np.zeros(2) if off is None else off
    real = tcp + off  # where the part really sat at grasp, relative to acceptance
    current = _unchanged_currents(w, start)
    place = "its acceptance place" if w.level is None else w.level[0]
    tail = [w.level[1]] if w.level is not None else []
    tail += [current] if current else []
    tail += [f"success fell to {np.mean([c.success for c in w.cycles if c.index >= start]):.0%} of cycles"
             ] if any(a.signal in ("success", "grasped") for a in outcome) else []
    seen_alarmed = any(a.signal.startswith(("part_seen_", "fixture_seen_")) for a in alarms)
    part, fiducial = w.xy("part_seen", start), w.xy("fixture_seen", start)
    if (seen_alarmed and part is not None and fiducial is not None and np.linalg.norm(part) >= SIGNIFICANT_MM
            and np.linalg.norm(fiducial) < SIGNIFICANT_MM):
        share = np.linalg.norm(part) / (np.linalg.norm(part) + np.linalg.norm(fiducial))
        words = (f"camera-seen part moved {_vec(part)}", f"camera-seen fixture fiducial unchanged ({_vec(fiducial)})",
                 "the part was presented off its place in a fixture that did not move: the part was misplaced")
        return Finding("part_misplaced", start, _squash(share), words + tuple(tail), signals)
    if seen_alarmed and np.linalg.norm(seen) >= SIGNIFICANT_MM:
        d_fixture, d_camera = float(np.linalg.norm(seen - real)), float(np.linalg.norm(real))
        moved = d_fixture <= d_camera
        share = (d_camera if moved else d_fixture) / max(d_fixture + d_camera, 1e-9)
        conf = _squash(share)
        words = (f"camera-seen part and fixture moved {_vec(seen)}", f"grasp pose moved {_vec(tcp)}",
                 f"part-to-tool offset at grasp changed {_vec(off)}")
        if moved:
            why = f"the part really sat {_vec(real)} from {place}, as the camera saw: the fixture moved"
            return Finding("fixture_shift", start, conf, words + (why,) + tuple(tail), signals)
        why = (f"the part really sat only {_vec(real)} from {place}: the camera moved, about {_vec(real - seen)} "
               "(the opposite of what it saw the part do; its calibration no longer holds)")
        return Finding("camera_shift", start, conf, words + (why,) + tuple(tail), signals)
    q = [w.zmed(n, start) for n in w.baseline.names if n.startswith("grasp_q.")]
    q_still = not q or np.linalg.norm(np.nan_to_num(q)) < UNCHANGED_Z
    stayed = _part_stayed(w, alarms, start)
    slip = w.xy("grasp_offset", start, "xyz")  # a tool that slipped along its axis moved the offset in z alone
    slip = off if slip is None else slip
    if np.linalg.norm(slip) >= SIGNIFICANT_MM and (q_still or not stayed):  # else the joints closed it elsewhere
        conf = _squash(np.linalg.norm(slip) / (np.linalg.norm(slip) + np.linalg.norm(seen))) if q_still else 0.4
        words = (f"part-to-tool offset at grasp changed {_vec(slip)}",
                 f"camera-seen part unchanged ({_vec(seen)})",
                 "joint grasp pose unchanged" if q_still else "joint grasp pose also changed",
                 "the tool point moved on the flange: the tool slipped")
        return Finding("tool_slip", start, conf, words + tuple(tail), signals)
    words = (f"geometry changed in no pattern of a known cause: {_moved(w, alarms, start)}",)
    if stayed and not (q and q_still):  # the joints' grasp pose moved (or is not read): they closed it elsewhere
        words += ("the part really sat where it did (grasp pose plus offset within "
                  f"{SIGNIFICANT_MM} mm of the camera's reading on every axis): the tool closed on it at another point",)
    return Finding("unknown", start, 0.3, words + tuple(tail), signals)


def _moved(w: _Window, alarms: Sequence[DriftAlarm], start: int) -> str:
    """The alarmed geometry features and their median change, in words."""
    return ", ".join(f"{a.signal} {_fmt(w.delta(a.signal, start))} mm" for a in _distinct(alarms)[:4]
                     if kind_of(a.signal).unit == "mm")


CONSEQUENCE_OF = ("policy_latency", "servo", "friction", "load_change")  # what changes where the tool closes


def _part_stayed(w: _Window, alarms: Sequence[DriftAlarm], start: int) -> bool:
    """Whether only the grasp moved: the camera saw nothing, and on each axis the grasp pose plus the
    part-to-tool offset (where the part really sat) stayed within ``SIGNIFICANT_MM`` of where the camera
    saw it, cycle by cycle (a stale plan that nudges the part moves both)."""
    if any(a.signal.startswith(("part_seen_", "fixture_seen_")) for a in alarms):
        return False
    real = [w.delta(f"grasp_tcp_{ax}_mm", start, [f"grasp_offset_{ax}_mm"], [f"part_seen_{ax}_mm"]) for ax in "xyz"]
    real = [r for r in real if np.isfinite(r)]
    return bool(real) and max(abs(r) for r in real) < SIGNIFICANT_MM


def _with_grasp(w: _Window, grasp: Finding, alarms: list[DriftAlarm], findings: list[Finding],
                when: str = "") -> list[Finding]:
    """``findings`` with the geometry finding ``grasp``: an unknown one where only the grasp moved (the
    part really sat where it did) is the consequence of a concurrent change in how the arm moves (a
    stale plan, a joint that lags or needs more torque closes the tool at another point of its path):
    told in that finding's evidence, on the cycles ``when`` says (from its first on by default)."""
    host = None
    if grasp.cause == "unknown" and _part_stayed(w, alarms, grasp.cycle):
        near = [f for f in findings if f.cause in CONSEQUENCE_OF and abs(f.cycle - grasp.cycle) <= CONCURRENT]
        host = min(near, key=lambda f: (abs(f.cycle - grasp.cycle), -f.confidence), default=None)
    if host is None:
        return findings + [grasp]
    note = (f"also {when or f'from cycle {grasp.cycle}'} the tool closed at another point of its path "
            f"({_moved(w, alarms, grasp.cycle)}), the part where it was",)
    return [told(f, note, grasp.signals) if f is host else f for f in findings]


def _pick_move(w: _Window, alarms: Sequence[DriftAlarm], start: int) -> float:
    """How far [mm] the arm's pick point moved from ``start`` on: the grasp pose's move where the camera saw the
    part move and the grasp pose followed it by ``SIGNIFICANT_MM`` or more; else 0."""
    tcp = w.xy("grasp_tcp", start)
    mm = float(np.linalg.norm(tcp)) if tcp is not None else 0.0
    return mm if any(a.signal.startswith(("part_seen_", "fixture_seen_")) for a in alarms) and mm >= SIGNIFICANT_MM \
        else 0.0


def _with_path(grasp: Finding, on_path: Sequence[tuple]) -> Finding:
    """The geometry finding ``grasp`` with the joints whose change is its new path's (``_on_path``) told in it."""
    words = tuple(f"also {r[2]} from cycle {r[0]}: {_torque(r)}, tracking error {_pct(r[4])}: the arm moves to "
                  "another pick point, not a change in its drive" for r in on_path)
    return told(grasp, words, [a.signal for r in on_path for a in r[6]]) if on_path else grasp


def _grounded(baseline: Baseline) -> bool:
    """Whether the robot stands on the ground (it has gait features): then the ground takes a share of
    its drives' work that shifts with the gait, and the friction torque speaks only where current and
    tracking error stayed quiet."""
    return any(kind_of(n).family == "gait" for n in baseline.names)


def _joints(w: _Window, groups: dict[str, list[DriftAlarm]], grounded: bool = False,
            new_paths: Sequence[tuple[int, float]] = ()) -> tuple[list[Finding], list[tuple]]:
    """One finding per cause and episode: joints of the same kind of change that start together; and,
    apart, the rated joints whose change is the arm's new path from a (cycle, grasp pose move [mm]) of
    ``new_paths`` on (``_on_path``).

    The torque a joint needs is read from its current and, where it alarmed (on a robot off the
    ground) or where current and tracking error stayed under ``QUIET``, from its friction torque."""
    rated = []
    for joint, alarms in groups.items():
        start = _onset(alarms)
        cur = _largest(w.relative(f"current_rms.{joint}", start), w.relative(f"current_peak.{joint}", start))
        trk = w.tracking(joint, start)
        alarmed = any(a.signal == f"friction_torque.{joint}" for a in alarms)
        speaks = max(abs(cur), abs(trk)) < QUIET or (alarmed and not grounded)
        ft = _friction(w, joint, start) if speaks else 0.0
        current, cur = cur, (ft if ft > max(cur, 0.0) else cur)
        c, t = max(cur, 0.0), max(trk, 0.0)
        if max(abs(cur), abs(trk)) < MATERIAL:
            continue  # statistically there, physically too small to name a cause for
        carry, free = w.relative(f"current_carry_rms.{joint}", start), w.relative(f"current_free_rms.{joint}", start)
        if np.isfinite(carry) and np.isfinite(free) and carry >= MATERIAL and free < CARRY_ONLY * carry:
            share = min(0.95, 1.0 - max(free, 0.0) / carry)
            rated.append((start, "load_change", joint, carry, free, share, alarms, 0.0, current))
            continue
        if max(c, t) < MATERIAL:  # what moved fell: no rise names friction or a weaker servo
            cause, share = "unknown", 0.5
        else:
            share = c / (c + t)
            cause = "friction" if share >= 0.5 else "servo"
            share = share if cause == "friction" else 1.0 - share
        rated.append((start, cause, joint, cur, trk, share, alarms, ft, current))
    rated.sort()
    rated, follows = _coupled(rated, grounded)
    allowance = {r[2]: _path_allowance(r, new_paths) for r in rated}
    rated, on_path = _on_path(rated, allowance)
    findings: list[Finding] = []
    while rated:
        start, cause = rated[0][0], rated[0][1]
        same = [r for r in rated if r[1] == cause and abs(r[0] - start) <= CONCURRENT]
        rated = [r for r in rated if r not in same]
        joints = tuple(r[2] for r in same)
        conf = _squash(float(np.mean([r[5] for r in same])))
        if cause == "load_change":
            evidence = [f"{r[2]}: current while carrying {_pct(r[3])}, while not {_pct(r[4])} vs baseline"
                        for r in same[:6]]
            evidence.append("the joints need more current only while they carry the part: the part's weight "
                            "changed (a new product variant?), not the joints")
        else:
            evidence = [f"{r[2]}: {_torque(r)}, tracking error {_pct(r[4])} vs baseline" for r in same[:6]]
        coupled = [(r, lead) for lead in joints for r in follows.get(lead, ())]
        evidence += [f"also {r[2]} from cycle {r[0]}: {_torque(r)}, tracking error {_pct(r[4])}, under "
                     f"{COUPLED:.0%} of {lead}'s change: the coupled joints follow it, not a second cause"
                     for r, lead in coupled[:3]]
        if cause == "friction":
            evidence.append("the torque rose more than the tracking error (the current, or on a loaded joint the "
                            "friction torque): the joint needs more torque to follow the same motion, so friction grew")
            if any(r[7] and r[7] == r[3] and r[8] < r[4] and r[4] >= QUIET for r in same):  # torque decided it
                evidence.append("a position servo holds the extra torque through a larger error, so its tracking error "
                                "rose with it; a weaker gain would have left the friction torque where it was")
        elif cause == "servo":
            evidence.append("the tracking error rose more than the current: the drive pushes less for the same "
                            "error, so the servo gain dropped")
        elif cause != "load_change":
            conf = 0.3
        path = max(allowance[j] for j in joints)
        if path and cause in ("servo", "friction"):  # its change against what the new path can make
            size = min(_size(r) for r in same)
            conf = min(conf, _squash(size / (size + path)))
            evidence.append(f"the arm also moves to another pick point, which moves a joint's current and tracking "
                            f"error by up to {path * 100:.1f} %: this change is more, its drive's (the confidence "
                            "allows for the path's share)")
        findings.append(Finding(cause, start, conf, tuple(evidence),
                                tuple(sorted({a.signal for r in same + [r for r, _ in coupled] for a in r[6]})),
                                joints))
    return findings, on_path


def _torque(r: tuple) -> str:
    """The torque a rated joint needs, in words: its current, or its friction torque where that spoke."""
    if r[7] and r[7] == r[3]:
        return f"friction torque {_pct(r[3])}" + (f", current {_pct(r[8])}" if abs(r[8]) >= MATERIAL else "")
    return f"current {_pct(r[3])}"


def _friction(w: _Window, joint: str, start: int) -> float:
    """Relative change of the joint's friction torque, where it stands out of its noise (else 0): on a
    loaded joint the current's RMS does not show friction, the work over the travel does."""
    name = f"friction_torque.{joint}"
    return w.relative(name, start) if abs(w.zmed(name, start)) >= UNCHANGED_Z else 0.0


def _coupled(rated: list[tuple], grounded: bool) -> tuple[list[tuple], dict[str, list[tuple]]]:
    """Split the rated joints (``_joints``'s tuples, by onset) into those that carry a cause and, per
    leading joint, those whose change is under ``COUPLED`` of its change and began no earlier, unless
    it is its own drive's (``_own_drive``)."""
    kept: list[tuple] = []
    follows: dict[str, list[tuple]] = {}
    for r in sorted(rated, key=_size, reverse=True):
        leads = [m for m in kept if m[1] != "load_change" and m[0] <= r[0] + CONCURRENT]
        lead = max(leads, key=_size, default=None)
        if (r[1] != "load_change" and lead is not None and _size(r) < COUPLED * _size(lead)
                and not _own_drive(r, lead, grounded)):
            follows.setdefault(lead[2], []).append(r)
        else:
            kept.append(r)
    return sorted(kept), follows


def _size(r: tuple) -> float:
    """A rated joint's change: the larger of its torque's and its tracking error's."""
    return max(abs(r[3]), abs(r[4]))


def _on_path(rated: list[tuple], allowance: dict[str, float]) -> tuple[list[tuple], list[tuple]]:
    """Split the rated joints into those that carry a cause and those whose change is the arm's new path:
    under its ``allowance`` (by joint, ``_path_allowance``), where the arm goes to another pick point (its joints move through
    other angles, at other speeds, so their errors and currents shift a little; a drive that changed with it
    changes more)."""
    moved = [r for r in rated if _size(r) < allowance[r[2]]]
    return [r for r in rated if r not in moved], moved


def _path_allowance(r: tuple, new_paths: Sequence[tuple[int, float]]) -> float:
    """How much of rated joint ``r``'s change a new path that began within ``CONCURRENT`` of it can make:
    ``PATH_PER_MM`` of each mm the grasp pose moved (the larger move if two), 0 where none did. The angles the
    path changes grow with the move: a fixed 2 % told a servo gain loss that came with a 2 mm camera shift
    (shoulder_lift error +2.0 %) as the new path's. A load change reads carrying against not carrying: its own."""
    mm = [m for cycle, m in new_paths if abs(r[0] - cycle) <= CONCURRENT]
    return PATH_PER_MM * max(mm) if mm and r[1] != "load_change" else 0.0


def _own_drive(r: tuple, lead: tuple, grounded: bool) -> bool:
    """Whether rated joint ``r``'s change is its own drive's, not ``lead``'s consequence: a coupled joint's
    change reaches it as a load, which a position servo answers with current (and the error that holds
    it), so an error that grew by ``QUIET`` or more with its current within ``MATERIAL`` is its own.
    Under a friction lead on a robot off the ground so is any error that rose more than its current
    (rated ``servo``): friction acts between the lead joint's own two links, whose drive supplies it and
    keeps the motion (its error rose a little), so the others feel a load no larger than that small lag
    makes (on an arm a friction x1.5 leaves the other joints' current and error within their noise).
    Off the ground so is a joint whose friction torque stood out of its noise and rose ``MATERIAL`` or more: the
    work its drive does over its own travel grew, which a coupled joint's load, answered by a little current
    (an arm's follower: 1.5 %), does not make (a wrist's friction x4 leaves the shoulder's within its noise).
    On a leg a joint rated friction may be one carrying a weak leg's share, not a lead of its own."""
    own_error = r[1] == "servo" and ((r[4] >= QUIET and abs(r[8]) < MATERIAL) or (lead[1] == "friction" and not grounded))
    return own_error or (not grounded and r[7] >= MATERIAL)


def _by_leg(alarms: Sequence[DriftAlarm]) -> dict[str, list[DriftAlarm]]:
    """Gait alarms grouped by the leg they belong to."""
    legs: dict[str, list[DriftAlarm]] = {}
    for a in alarms:
        legs.setdefault(member_of(a.signal), []).append(a)
    return legs


def _feet(w: _Window, alarms: list[DriftAlarm]) -> list[Finding]:
    """Gait timing of one leg changed (contact duty, touchdown lag): a foot contact change, per leg.
    The diagnosis drops it where a joint finding on the same leg explains it."""
    legs = _by_leg(alarms)
    out = []
    for leg, group in sorted(legs.items()):
        start = _onset(group)
        evidence = tuple(f"{a.signal} {_fmt(w.delta(a.signal, start))} vs baseline" for a in _distinct(group)[:4])
        out.append(Finding("foot_contact", start, 0.6, evidence + (
            f"leg {leg}'s foot meets the ground differently with its joints' drive unchanged: a worn or "
            "slipping foot, or the ground under it",), tuple(sorted({a.signal for a in group})), legs=(leg,)))
    return out


def intermittent_finding(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, found,
                         shift: np.ndarray | None = None) -> Finding:
    """Name an intermittent pattern from its hit cycles alone, the way a persistent one is named (``shift``: as
    ``name_causes``'s)."""
    w, alarms = _on_hits(baseline, cycles, z, found, shift)
    named = _geometry(w, alarms, []) if found.family == "geometry" else Finding(
        "unknown", found.first, 0.3, (f"{', '.join(found.signals[:4])} off on some cycles",), found.signals)
    watched = len(cycles) - next(i for i, c in enumerate(cycles) if c.index == found.first)
    head = (f"intermittent: {len(found.cycles)} of {watched} cycles from cycle {found.first} on ({found.rate:.0%}), "
            f"{_hit_cycles(found)}",) if not found.clean else _at_acceptance_words(baseline, found)
    # the drives are watched on the cycles between its hits: a hit that dropped the part says nothing of them
    evidence = tuple(e for e in named.evidence if not e.startswith(DRIVES_UNWATCHED))
    return Finding(named.cause, found.first, named.confidence, head + evidence, named.signals, rate=found.rate)


def _at_acceptance_words(baseline: Baseline, found) -> tuple[str, ...]:
    """The head of a finding for an intermittent fault the baseline holds (``intermittent._at_acceptance``)."""
    held = ", ".join(f"{baseline.median(s):+.1f} mm in {s.removeprefix(AT_ZERO)[0]}" for s in found.signals)
    return (f"intermittent, present at acceptance: {len(found.cycles)} of {len(found.cycles) + len(found.clean)} "
            f"cycles ({found.rate:.0%}), {_hit_cycles(found)}",
            f"the acceptance baseline holds it: part-to-tool offset at grasp {held} there, where a tool that holds "
            f"its place reads 0; the other cycles were back at 0 (cycles {_shown(found.clean)}), the fault absent, "
            "not a new change")


def _on_hits(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, found,
             shift: np.ndarray | None = None) -> tuple[_Window, list[DriftAlarm]]:
    """The window over an intermittent pattern's hit cycles, and its features as alarms from its first. Where the
    baseline holds the fault, the hits are read from the clean cycles' level: the baseline is the fault's."""
    rows = np.array([c.index in set(found.cycles) for c in cycles])
    w = _Window(baseline, cycles, z, shift)
    if found.clean:
        w = w.read_from(np.array([c.index in set(found.clean) for c in cycles]), (
            "where it sat on the cycles the fault spared",
            f"each change read from the cycles the fault spared (cycles {_shown(found.clean)}), not from acceptance, "
            "which held it"))
    w = w._rows(rows)
    return w, [DriftAlarm(s, found.first, 0.0, found.first, 0) for s in _off_on_hits(w, found)]


def _shown(cycles: Sequence[int]) -> str:
    return f"{', '.join(str(i) for i in cycles[:8])}{' ...' if len(cycles) > 8 else ''}"


def _hit_cycles(found) -> str:
    return f"cycles {_shown(found.cycles)}"


def _off_on_hits(w: _Window, found) -> tuple[str, ...]:
    """The features of an intermittent pattern: those that crossed the outlier line and, for geometry,
    those off by ``UNCHANGED_Z`` or more in the median over its hit cycles (``w``'s), under the line on
    each (a part presented 3 mm off reads about 5 scales in the camera on every cycle it is off)."""
    if found.family != "geometry":
        return tuple(found.signals)
    off = {n for n in w.baseline.names
           if kind_of(n).family == "geometry" and abs(w.zmed(n, found.first)) >= UNCHANGED_Z}
    return tuple(sorted(off.union(found.signals)))


def intermittent_findings(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, found: Sequence,
                          findings: Sequence[Finding] = (), shift: np.ndarray | None = None) -> list[Finding]:
    """``findings`` (the persistent ones) and each intermittent pattern named (``intermittent_finding``); a
    pattern with no known cause whose cycles are all cycles of a named one (the place error off on the cycles
    the tool slipped), or of a geometry one, is that fault seen again, told in its evidence. A geometry pattern
    where only the grasp moved is told in a concurrent finding of how the arm moves, as a persistent one is
    (``_with_grasp``: a latency on a few cycles closes the tool elsewhere on just those). ``shift``: as
    ``name_causes``'s."""
    named = [(f, intermittent_finding(baseline, cycles, z, f, shift)) for f in found]
    hosts = {id(f): next((g for g, other in named if (other.cause != "unknown" or g.family == "geometry")
                          and g is not f and set(f.cycles) <= set(g.cycles)), None)
             if finding.cause == "unknown" else None for f, finding in named}
    out = list(findings)
    for g, finding in named:
        if hosts[id(g)] is not None:
            continue
        same = [f for f, _ in named if hosts[id(f)] is g]
        words = tuple(f"also {', '.join(f.signals[:4])} off on {'the same' if f.cycles == g.cycles else 'some of its'} "
                      "cycles" for f in same)
        finding = told(finding, words, [s for f in same for s in f.signals])
        if g.family == "geometry":
            w, alarms = _on_hits(baseline, cycles, z, g, shift)
            out = _with_grasp(w, finding, alarms, out, when=f"on {_hit_cycles(g)}")
        else:
            out.append(finding)
    return out


UNCHANGED_CURRENT = "current unchanged"
DRIVES_UNWATCHED = "drives not watched"


def _unchanged_currents(w: _Window, start: int) -> str:
    """``UNCHANGED_CURRENT`` where every joint's current RMS stayed within ``UNCHANGED_Z`` scales (a geometry
    finding says so; it drops the line beside a joint finding that began with it, or a joint told in it as the new
    path's whose current moved ``MATERIAL`` or more). Where the currents were watched on fewer cycles from ``start``
    on than a baseline needs (``MIN_CYCLES``) while more were there (the others at another load), it says the drives
    went unwatched instead: a 4 mm camera shift fails most grasps, and one grasped cycle's "unchanged" ruled out the
    servo fault that came with it."""
    cols = [j for j, n in enumerate(w.baseline.names) if n.startswith("current_rms.")]
    rows = [i for i, c in enumerate(w.cycles) if c.index >= start]
    watched = int(np.sum(~np.all(np.isnan(w.z[np.ix_(rows, cols)]), axis=1))) if cols else 0
    if cols and watched < min(MIN_CYCLES, len(rows)):
        return (f"{DRIVES_UNWATCHED}: joint currents watched on {watched} of its {len(rows)} cycles, too few to rule "
                "out a drive fault (a cycle at another load than the acceptance, no part grasped, or settling after a "
                "declared change is not watched)")
    zs = [abs(w.zmed(n, start)) for n in w.baseline.names if n.startswith("current_rms.")]
    zs = [z for z in zs if np.isfinite(z)]
    return UNCHANGED_CURRENT if zs and max(zs) < UNCHANGED_Z else ""


def _largest(*values: float) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return max(finite, key=abs) if finite else 0.0


def _squash(share: float) -> float:
    """Map a share in [0.5, 1] of the evidence for the winning reading onto a confidence."""
    return float(np.clip(0.5 + 0.9 * (share - 0.5), 0.5, 0.95))


def _vec(v: np.ndarray) -> str:
    return ", ".join(f"{d:+.1f} mm in {axis}" for d, axis in zip(v, "xyz"))


def _pct(r: float) -> str:
    return f"{r * 100:+.1f} %"


def _fmt(v: float) -> str:
    return f"{v:+.3g}"
