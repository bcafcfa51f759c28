"""The residual monitor's alarms as diagnosis input: evidence on a matching finding, else ``model_drift``.

A run watched by ``calibrate.residual`` carries, in each cycle's outcome, ``residual.alarms``: the
joint whose measured torque left its model and the likely parameter. A finding that already names
that joint with a matching cause (``friction`` for a friction-like residual; ``servo`` for an
inertia-like one, a weaker servo's changed motion, and on a robot on its feet for a friction-like one too)
gains the alarm as evidence; an alarm that comes with a change the joint model cannot follow is told in
that change's finding, as ``cause`` tells the joints that change with it: a policy latency (from ``CONCURRENT``
cycles before it to the monitor's latency after it began) is the stale plan's motion, and on a robot on its feet
a weaker servo (up to the monitor's latency after it began) leaves its share of the body to the other legs, both
against foot forces the joint model does not hold; otherwise the alarm becomes a ``model_drift`` finding of its
own, whose advice is the re-fit its cell allows (a robot on its feet is excited on a stand: ``identify`` refuses
a free base's record; payload only where the monitor's model has one).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import replace

from cellguard.diagnose.cause import CONCURRENT, Finding, told
from cellguard.diagnose.cycles import as_cycles, getter
from cellguard.diagnose.feature_kinds import kind_of

# A weaker servo moves its joint otherwise (it lags, accelerates later): the residual of the model over that
# motion then shifts along the acceleration, read as inertia-like, with no change of the arm's mass.
MATCHES = {"friction": ("friction",), "inertia/payload": ("tool_slip", "part_misplaced", "servo"), "delay": ("servo",)}
# On its feet a weaker servo's leg carries less of the body: its foot forces, which the joint model does not hold,
# change, and the model reads that as friction (a fr_knee servo gain x0.8 on the quadruped: friction -0.58 N*m).
ON_FEET = {"friction": ("servo",)}
WHY = {("inertia/payload", "servo"): " (the weaker servo moves the joint otherwise; the model reads that as inertia)",
       ("friction", "servo"): " (the weaker leg carries less of the body, against foot forces the model does not "
                              "hold; the model reads that as friction)"}
# Per cause of a change the joint model cannot follow: what the joints do with it, what to fix first (``_told_with``)
WITH = {"policy_latency": ("the joints move to the stale plan", "latency"),
        "servo": ("the other legs take the weak leg's share", "servo")}
CONFIDENCE = 0.7
# what to re-fit, per likely parameter ({} the joint); payload is offered where the model has one (``_refit``)
REFIT = {"friction": "--only {},friction", "inertia/payload": "--only {},armature", "delay": "--params delay"}


def residual_alarms(rows: Iterable[object]) -> list[dict]:
    """The alarms carried by cycle rows (mappings or objects with an ``outcome``), in cycle order, each with
    what its re-fit depends on: ``payload`` (the monitor's model has a payload signature) and ``stand`` (the
    robot stands on its feet: its row has gait features); and ``lag``, the monitor's latency in cycles: a change
    that lasts alarms on its second window of the same motion (a window's score is capped), so up to two rounds
    of the cell's motions after it began (a change begun within a cycle: its second full window), 4 cycles on a
    cell that alternates left and right turns."""
    rows = list(rows)
    lag = 2 * len({c.label for c in as_cycles(rows)})
    out = []
    for row in rows:
        get = getter(row)
        outcome = get("outcome")
        residual = outcome.get("residual") if isinstance(outcome, Mapping) else None
        if isinstance(residual, Mapping):
            features = get("features") if isinstance(get("features"), Mapping) else {}
            cell = {"payload": "payload" in (residual.get("signatures") or ()),
                    "stand": any(kind_of(n).family == "gait" for n in features), "lag": lag}
            out += [{**a, **cell, "cycle": get("cycle")} for a in residual.get("alarms") or []
                    if isinstance(a, Mapping)]
    return sorted(out, key=lambda a: (a["cycle"] is None, a["cycle"] or 0))


def with_residual(findings: list[Finding], alarms: list[dict]) -> list[Finding]:
    """``findings`` with each alarm added as evidence to a matching one, told in the change it came with
    (``_came_with``: a policy latency, a weaker servo on a robot on its feet), or as a ``model_drift`` finding."""
    findings = list(findings)
    told_in: dict[int, list[dict]] = {}  # per finding (its place in findings), the alarms that came with its change
    for a in alarms:
        words = f"residual monitor, cycle {a['cycle']}: {a.get('message', a['parameter'])}"
        match = next((i for i, f in enumerate(findings) if a["joint"] in f.joints and f.cause in _matching(a)), None)
        along = next((i for i, f in enumerate(findings) if _came_with(a, f)), None)
        if match is not None:
            f = findings[match]
            signal = f"residual.{a['joint']}.{a['signature']}"
            findings[match] = replace(f, evidence=f.evidence + (words + WHY.get((a["parameter"], f.cause), ""),),
                                      signals=f.signals + (signal,))
        elif along is not None:
            told_in.setdefault(along, []).append(a)
        else:
            findings.append(Finding("model_drift", int(a["cycle"] or 0), CONFIDENCE, (
                words, f"likely parameter: {a['parameter']}; {_refit(a)} re-fits it (a run record is 50 Hz between "
                       "events)"), (f"residual.{a['joint']}.{a['signature']}",), (a["joint"],)))
    return [_told_with(f, told_in[i]) if i in told_in else f for i, f in enumerate(findings)]


def _matching(alarm: dict) -> tuple[str, ...]:
    """The causes of a finding on ``alarm``'s joint that its likely parameter tells of (``ON_FEET`` too on a robot
    on its feet, where the joint's friction-like residual fell: a weak leg carries less; one that rose is friction
    the servo finding may have misread, kept as its own finding with its re-fit)."""
    fell = isinstance(alarm.get("change"), (int, float)) and alarm["change"] < 0
    feet = ON_FEET.get(alarm["parameter"], ()) if alarm.get("stand") and fell else ()
    return MATCHES.get(alarm["parameter"], ()) + feet


def _came_with(alarm: dict, f: Finding) -> bool:
    """Whether ``alarm`` came with ``f``'s change, one the joint model cannot follow: a policy latency, or on a robot
    on its feet a weaker servo on other joints; from ``CONCURRENT`` cycles before it began to the monitor's latency
    (``lag``) after it began. Not later, whether the change lasts or not: an alarm then is a change of its own (up to
    the latency's last cycle, an elbow friction x1.5 six cycles after a lasting latency on the arm was told in it)."""
    if alarm["cycle"] is None or f.cause not in WITH:
        return False
    if f.cause == "servo" and (not alarm.get("stand") or alarm["joint"] in f.joints):  # its own: ``_matching``
        return False
    return f.cycle - CONCURRENT <= alarm["cycle"] <= f.cycle + alarm.get("lag", CONCURRENT)


def _told_with(f: Finding, alarms: list[dict]) -> Finding:
    """The finding ``f`` with the residual ``alarms`` that came with its change told in it: the joints move
    otherwise (to a stale plan; the other legs carry a weak leg's share), against loads the joint model does not
    hold (a leg's foot forces), so the model's torque no longer fits them; not a drift of the model (a drive that
    changed at the same cycle would read the same)."""
    kinds = sorted({a["parameter"] for a in alarms})
    note = (f"also the residual monitor from cycle {min(a['cycle'] for a in alarms)} at "
            f"{', '.join(a['joint'] for a in alarms)} ({'-, '.join(kinds)}-like): {WITH[f.cause][0]}, "
            f"against loads the model does not hold, not a drift of the model (check these joints once the "
            f"{WITH[f.cause][1]} is fixed)",)
    return told(f, note, [f"residual.{a['joint']}.{a['signature']}" for a in alarms])


def _refit(alarm: dict) -> str:
    """The calls that re-fit ``alarm``'s likely parameter on its cell: an excitation record (on a stand for a
    robot on its feet, whose free base ``identify`` cannot fit from), then ``identify`` of that parameter (payload
    offered only where the monitor's model has one; a hand-made alarm is taken for an arm's)."""
    refit = REFIT.get(alarm["parameter"], "--params {}").format(alarm["joint"])
    if alarm["parameter"] == "inertia/payload" and alarm.get("payload", True):
        refit += " (or --params payload)"
    stand = " --stand" if alarm.get("stand") else ""
    return f"`cellguard excite CELL{stand} --seconds 20 --out DIR`, then `cellguard identify DIR {refit}`"
