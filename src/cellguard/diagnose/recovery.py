"""Recoveries in a diagnosis: the ``recovery`` cause, what got the cell running again, and advice.

Read from each cycle's ``recovery_log`` (one entry per attempt, see ``RecoveryOutcome``), and for the cycle a run
was killed in (no row) from the fields of its ``recovery_end`` events; never from their words (rewording an event
changes no diagnosis) but in a record written before events carried the fields.

- a recovery that made things worse is a finding of its own, cause ``recovery``: attempts that
  arrived at their contact pose later than the acceptance attempts of the same behaviour and trigger did (a
  ``back_off`` at half speed is no late ``retry_grasp``), or after the gripper was told to shut, attempts
  repeated without effect, or a cycle after a recovery that failed where others did not;
- every finding gains what got the cell running again in its cycles (the behaviours that resumed
  it, with counts);
- advice: for each finding, the behaviours that fixed the same cause in this site's other records,
  ranked by success rate, with their counts.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from types import MappingProxyType

import numpy as np

from cellguard.control.events import EventKind
from cellguard.diagnose.cause import Finding
from cellguard.diagnose.cycles import Cycle, as_cycle, as_cycles, getter
from cellguard.diagnose.feature_kinds import kind_of
from cellguard.robot.recovery.outcome import RecoveryOutcome

LATE = 1.25  # an arrival later than this multiple of the acceptance recoveries' median is late
LATE_MIN_S = 0.1  # [s] and at least this much later
MIN_LATE = 2  # late attempts before the cause is named
NEXT_WORSE = 0.5  # the cycle after a recovery fails this much more often than the others
MIN_BASELINE = 3  # acceptance cycles without a recovery needed to leave the others' motion out of the baseline
KEPT = frozenset({"success", "grasped", "timed_out"})  # outcome features a recovery cycle still speaks for


def _recovered(c: Cycle) -> bool:
    return c.features.get("recoveries", 0.0) > 0


def policy_cycles(acceptance: Sequence[Cycle]) -> list[Cycle]:
    """The acceptance cycles as the baseline should see them: on a cycle a recovery drove, only its
    grasp geometry and whether it succeeded (its motion is not the policy's), as long as at least
    ``MIN_BASELINE`` cycles the policy drove alone describe the motion; else every cycle as it is."""
    if sum(not _recovered(c) for c in acceptance) < MIN_BASELINE:
        return list(acceptance)
    return [replace(c, features=MappingProxyType({k: v for k, v in c.features.items() if _kept(k)}))
            if _recovered(c) else c for c in acceptance]


def _kept(name: str) -> bool:
    return kind_of(name).family == "geometry" or name in KEPT


def without_recovery_motion(names: Sequence[str], cycles: Sequence[Cycle], z: np.ndarray) -> np.ndarray:
    """``z`` (Shape (cycles, features)) with what a recovery moved set to NaN on cycles that ran one:
    joints, timing and placement were the recovery's; the grasp geometry (the policy's own first
    grasp) and whether the cycle succeeded still count."""
    rows = [i for i, c in enumerate(cycles) if _recovered(c)]
    if not rows:
        return z
    cols = [j for j, n in enumerate(names) if not _kept(n)]
    z = z.copy()
    z[np.ix_(rows, cols)] = np.nan
    return z


def attempts_of(rows: Iterable[object], events: Iterable[object] = ()) -> list[tuple[int, RecoveryOutcome]]:
    """(cycle, attempt) for every recovery attempt, in cycle order, from the cycle rows' ``recovery_log`` (at the top
    of a run's outcome, inside ``outcome`` of a record's cycle); an entry that is not a whole attempt is left out.
    A row is written at its cycle's end, so the cycle a run was killed in has none: its attempts are read from its
    ``recovery_end`` events (``events``, each with its ``cycle``), as ``_unlogged`` says."""
    out, logged = [], set()
    for row in rows:
        get = getter(row)
        outcome = get("outcome")
        log = outcome.get("recovery_log") if isinstance(outcome, Mapping) else get("recovery_log")
        attempts = [RecoveryOutcome.from_dict(entry) for entry in (log if isinstance(log, list) else ())]
        index = as_cycle(row).index
        logged.add(index)
        out += [(index, done) for done in attempts if done is not None]
    out += _unlogged(events, logged)
    return sorted(out, key=lambda a: a[0])  # stable: a cycle's attempts stay in their order


def _unlogged(events: Iterable[object], logged: set[int]) -> list[tuple[int, RecoveryOutcome]]:
    """The attempts of cycles with no row in ``logged``, from the fields their ``recovery_end`` events carry; their
    words only in a record none of whose events carries the fields (written before they did)."""
    ends = [(get("cycle"), get("recovery"), get("reason")) for get in map(getter, events)
            if get("kind") == EventKind.RECOVERY_END]
    worded = all(fields is None for _, fields, _ in ends)
    out = []
    for cycle, fields, reason in ends:
        if type(cycle) is int and cycle not in logged:
            done = RecoveryOutcome.parse(str(reason)) if worded else RecoveryOutcome.from_dict(fields)
            out += [(cycle, done)] if done is not None else []
    return out


def acceptance_attempts(rows: Iterable[object]) -> list[tuple[int, RecoveryOutcome]]:
    """(cycle, attempt) for the attempts of the acceptance cycles among a record's cycle ``rows``: the reference its
    recoveries, or those of a record diagnosed against its acceptance, are judged against."""
    rows = list(rows)
    accepted = {c.index for c in as_cycles(rows) if c.phase == "acceptance"}
    return [(c, o) for c, o in attempts_of(rows) if c in accepted]


def recovery_finding(cycles: Sequence[Cycle], attempts: Sequence[tuple[int, RecoveryOutcome]],
                     reference: Sequence[tuple[int, RecoveryOutcome]] | None = None) -> Finding | None:
    """The ``recovery`` cause, if recoveries in the watched cycles arrived late, repeated without effect, or left a
    failing next cycle; None otherwise. ``reference``: the acceptance attempts of another record whose acceptance is
    the baseline (``acceptance_attempts``); every cycle is watched then, as the drift monitors watch them. None: this
    record's own acceptance attempts, and its production cycles watched."""
    phase = {c.index: c.phase for c in cycles}
    which = "cycles"
    if reference is None:
        which = "production cycles"
        reference = [(c, o) for c, o in attempts if phase.get(c) == "acceptance"]
        attempts = [(c, o) for c, o in attempts if phase.get(c) != "acceptance"]
        cycles = [c for c in cycles if c.phase != "acceptance"]
    acc = [o for _, o in reference]
    ended = [(c, o) for c, o in attempts if c in phase]  # no row: killed in it, its outcome unknown, none judged
    evidence, starts, shares = [], [], []
    refs = _arrivals(acc)
    judged = [(c, o) for c, o in ended if _judged(o)]
    late = [(c, o) for c, o in judged if _late(o, refs.get(_key(o)))]
    if len(late) >= MIN_LATE:
        start = late[0][0]
        since = [o for c, o in judged if c >= start]
        groups: dict[tuple[str, str], list[RecoveryOutcome]] = {}
        for _, o in late:  # each kind told on its own: pooled, the medians were times no attempt had
            groups.setdefault(_key(o), []).append(o)
        paces = {k: _pace(k, group, refs) for k, group in sorted(groups.items())}
        said = next(iter(paces.values())) if len(paces) == 1 else \
            ": " + "; ".join(f"{len(groups[k])} of {k[0]}{pace}" for k, pace in paces.items())
        evidence.append(f"{len(late)} recovery attempts from cycle {start} on arrived at contact{said}")
        shut = [closed + (f" ({k[0]})" if len(groups) > 1 else "") for k, group in sorted(groups.items())
                if (closed := _shut(group))]
        if shut:
            evidence.append(f"their gripper was told to shut at {'; '.join(shut)}: the fingers closed above the part")
        late_cycles = {c for c, _ in late}
        resumed = {c for c, o in ended if c in late_cycles and o.resumed_cell()}
        acc_cycles = {c for c, _ in reference}
        acc_resumed = {c for c, o in reference if o.resumed_cell()}
        evidence.append(f"they picked the part again in {len(resumed)} of {len(late_cycles)} cycles vs "
                        f"{len(acc_resumed)} of {len(acc_cycles)} at acceptance")
        evidence.append("the arm ran slower than the recovery's plan while the gripper kept its timing: a speed "
                        "scaling of the recovery, not the part, the tool or the fixture")
        starts.append(start)
        shares.append(len(late) / max(len(since), 1))
    useless = _without_effect(acc, ended, which)
    if useless is not None:
        evidence.append(useless[1])
        starts.append(useless[0])
        shares.append(0.6)
    worse = _next_cycle(cycles)
    if worse is not None:
        evidence.append(worse[1])
        starts.append(worse[0])
        shares.append(0.6)
    if not evidence:
        return None
    conf = float(np.clip(0.5 + 0.45 * max(shares), 0.5, 0.95))
    return Finding("recovery", min(starts), conf, tuple(evidence), ("recovery_arrival_s", "recoveries_failed"))


def _pace(key: tuple[str, str], group: Sequence[RecoveryOutcome], refs: dict[tuple[str, str], list[float]]) -> str:
    """When the late attempts of one kind arrived at contact, against that kind's acceptance attempts."""
    arrived = [o.arrival_s for o in group if o.arrival_s is not None]
    when = f"{np.median(arrived):.2f} s after they started (median)" if arrived else "never"
    if key not in refs:
        return f" {when} (no acceptance recoveries of {key[0]} after {key[1]} to compare)"
    return (f" {when} vs {np.median(refs[key]):.2f} s for the {len(refs[key])} acceptance recoveries ({key[0]} after "
            f"{key[1]})")


def _shut(group: Sequence[RecoveryOutcome]) -> str:
    """When the late attempts of one kind told the gripper to shut, where that was before the arm arrived (median
    of the kind's own); empty otherwise."""
    arrived = [o.arrival_s for o in group if o.arrival_s is not None]
    close = float(np.median([o.close_s for o in group]))
    if arrived and np.median(arrived) <= close:
        return ""
    return f"{close:.2f} s" + (f", {np.median(arrived) - close:.2f} s before the arm arrived" if arrived else "")


def _key(o: RecoveryOutcome) -> tuple[str, str]:
    return o.behaviour, o.trigger


def _arrivals(acc: Sequence[RecoveryOutcome]) -> dict[tuple[str, str], list[float]]:
    """The acceptance arrivals per (behaviour, trigger): each behaviour's plan has its own pace (``back_off`` runs
    at its ``speed_scale``), so an attempt is compared only with its own kind; pooled, a cell that escalated
    ``retry_grasp`` (1.6 s) to ``back_off`` (3.2 s) every cycle read every production ``back_off`` as late."""
    out: dict[tuple[str, str], list[float]] = {}
    for o in acc:
        if o.arrival_s is not None:
            out.setdefault(_key(o), []).append(o.arrival_s)
    return out


def _judged(o: RecoveryOutcome) -> bool:
    """Whether the attempt's arrival says anything: it had a contact (``close_s``), and it arrived or ran its plan
    out; one ``cut_off`` before it arrived (a stop, the cycle's end) was never given the time to."""
    return o.close_s is not None and (o.arrival_s is not None or o.outcome != "cut_off")


def _late(o: RecoveryOutcome, ref: Sequence[float] | None) -> bool:
    """Never arrived, arrived after the gripper was told to shut, or later than ``ref`` (the acceptance arrivals of
    its behaviour and trigger; None: none to compare, only the gripper's timing judges it)."""
    if o.arrival_s is None or o.arrival_s > o.close_s:
        return True
    ref_s = float(np.median(ref)) if ref else None
    return ref_s is not None and o.arrival_s > max(ref_s * LATE, ref_s + LATE_MIN_S)


def _without_effect(acc, watched, which: str) -> tuple[int, str] | None:
    """Watched cycles (``which``, in words) whose recoveries never resumed the cell (``RecoveryOutcome.resumed_cell``:
    an operator hand-over or a rehome that ran out does not), where acceptance ones did."""
    cycles: dict[int, list[RecoveryOutcome]] = {}
    for c, o in watched:
        cycles.setdefault(c, []).append(o)
    stuck = sorted(c for c, os in cycles.items() if len(os) > 1 and not any(o.resumed_cell() for o in os))
    acc_ok = not acc or np.mean([o.outcome in ("resumed", "failed") for o in acc]) >= 0.8
    if len(stuck) < MIN_LATE or not acc_ok or len(stuck) < 0.5 * len(cycles):
        return None
    tries = sum(len(cycles[c]) for c in stuck)
    return stuck[0], (f"recoveries repeated without effect in {len(stuck)} of {len(cycles)} {which} "
                      f"with a recovery ({tries} attempts, none resumed the cell)")


def _next_cycle(cycles: Sequence[Cycle]) -> tuple[int, str] | None:
    """Watched ``cycles`` right after a recovery fail more often than the others."""
    after = [c for c in cycles if c.features.get("after_recovery", 0.0) > 0]
    other = [c for c in cycles if c.features.get("after_recovery", 0.0) == 0 and not c.features.get("recoveries")]
    if len(after) < MIN_LATE or not other:
        return None
    bad_after = sum(not c.success for c in after) / len(after)
    bad_other = sum(not c.success for c in other) / len(other)
    if bad_after - bad_other < NEXT_WORSE:
        return None
    first = next(c.index for c in after if not c.success)
    return first, (f"the cycle after a recovery failed in {sum(not c.success for c in after)} of {len(after)} "
                   f"vs {bad_other:.0%} of the others: the recovery left the cell worse for the next cycle")


def fixes(findings: Sequence[Finding], cycles: Sequence[Cycle],
          attempts: Sequence[tuple[int, RecoveryOutcome]]) -> list[dict]:
    """Per finding and behaviour: cycles it ran in (``tried``) and those it resumed and that then
    succeeded (``fixed``). A cycle belongs to the latest finding that started by then. A cycle with no row (the one a
    run was killed in) is left out: whether it succeeded is unknown, and a guess would reach later records' advice."""
    success = {c.index: c.success for c in cycles}
    onsets = sorted({f.cycle for f in findings})
    out = []
    for f in findings:
        later = [o for o in onsets if o > f.cycle]
        end = later[0] if later else None
        ran: dict[str, dict[int, bool]] = {}
        for c, o in attempts:
            if c < f.cycle or (end is not None and c >= end) or c not in success:
                continue
            ok = o.outcome == "resumed" and success[c]
            ran.setdefault(o.behaviour, {})[c] = ran.get(o.behaviour, {}).get(c, False) or ok
        for behaviour, by_cycle in sorted(ran.items()):
            out.append({"cause": f.cause, "cycle": f.cycle, "recovery": behaviour, "tried": len(by_cycle),
                        "fixed": sum(by_cycle.values())})
    return out


def with_running_again(findings: Sequence[Finding], own: Sequence[dict]) -> list[Finding]:
    """Each finding with a line saying what got the cell running again in its cycles."""
    out = []
    for f in findings:
        mine = [r for r in own if r["cause"] == f.cause and r["cycle"] == f.cycle]
        if not mine:
            out.append(f)
            continue
        fixed = [r for r in mine if r["fixed"]]
        line = ("what got the cell running again: " + ", ".join(
            f"{r['recovery']} ({r['fixed']} of {r['tried']} cycles)" for r in fixed) if fixed else
            "no recovery got the cell running again (" + ", ".join(
                f"{r['recovery']} tried in {r['tried']} cycles" for r in mine) + ")")
        out.append(replace(f, evidence=f.evidence + (line,)))
    return out


def advice(findings: Sequence[Finding], history: Sequence[Mapping]) -> list[dict]:
    """For each finding, the behaviours that fixed the same cause in ``history``, this site's first,
    best success rate first. A row is one of this site's other records (``fixes``, with its
    ``record``; a ``scope`` it carries is not its to claim) or, with ``scope: fleet`` and no ``record``, the
    fleet store's k-anonymous count over other sites (``customers``)."""
    out = []
    for f in findings:
        pooled: dict[tuple[str, str], dict] = {}
        for row in history:
            if row.get("cause") != f.cause:
                continue
            scope = "site" if "record" in row else row.get("scope", "site")
            p = pooled.setdefault((scope, row["recovery"]), {"recovery": row["recovery"], "fixed": 0, "tried": 0,
                                                               "records": set(), "scope": scope})
            p["fixed"] += int(row["fixed"])
            p["tried"] += int(row["tried"])
            p["records"].add(row.get("record", ""))
            if scope == "fleet":  # the store's count of distinct customers behind the row
                p["customers"] = max(p.get("customers", 0), int(row["customers"]))
        ranked = sorted(pooled.values(), key=lambda p: (p["scope"] != "site", -p["fixed"] / max(p["tried"], 1),
                                                        -p["fixed"], p["recovery"]))
        if ranked:
            out.append({"cause": f.cause, "cycle": f.cycle, "recoveries": [
                {**p, "records": len(p["records"]), "success_rate": round(p["fixed"] / max(p["tried"], 1), 3)}
                for p in ranked]})
    return out


def advice_lines(advised: Sequence[Mapping]) -> dict[tuple[str, int], str]:
    """(cause, cycle) -> one line of advice, for the text and the report."""
    lines = {}
    for a in advised:
        site = [f"{r['recovery']} fixed it in {r['fixed']} of {r['tried']} cycles ({r['records']} record(s))"
                for r in a["recoveries"] if r["scope"] == "site"]
        fleet = [f"{r['recovery']} fixed it in {r['fixed']} of {r['tried']} signatures ({r['customers']} customers)"
                 for r in a["recoveries"] if r["scope"] == "fleet"]
        parts = ([f"seen before at this site: {', '.join(site)}"] if site else []) + \
                ([f"at other sites in the fleet: {', '.join(fleet)}"] if fleet else [])
        lines[a["cause"], a["cycle"]] = "; ".join(parts)
    return lines
