"""The residual monitor's alarms as diagnosis input: evidence on a matching finding, else ``model_drift``.

A run watched by ``calibrate.residual`` carries, in each cycle's outcome, ``residual.alarms``: the
joint whose measured torque left its model and the likely parameter. A finding that already names
that joint with a matching cause (``friction`` for a friction-like residual; ``servo`` for an
inertia-like one, a weaker servo's changed motion) gains the alarm as evidence; an alarm that arrives
with a policy latency (within ``CONCURRENT`` cycles of it) is the stale plan's motion, against loads the
joint model does not hold (a leg's foot forces), told in that finding as ``cause`` tells the joints that
change with it; otherwise the alarm becomes a ``model_drift`` finding of its own, whose advice is the
re-fit its cell allows (a robot on its feet is excited on a stand: ``identify`` refuses a free base's
record; payload only where the monitor's model has one).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from cellguard.diagnose.cause import CONCURRENT, Finding, told
from cellguard.diagnose.feature_kinds import kind_of

# A weaker servo moves its joint otherwise (it lags, accelerates later): the residual of the model over that
# motion then shifts along the acceleration, read as inertia-like, with no change of the arm's mass.
MATCHES = {"friction": ("friction",), "inertia/payload": ("tool_slip", "part_misplaced", "servo"), "delay": ("servo",)}
WHY = {("inertia/payload", "servo"): " (the weaker servo moves the joint otherwise; the model reads that as inertia)"}
CONFIDENCE = 0.7
# what to re-fit, per likely parameter ({} the joint); payload is offered where the model has one (``_refit``)
REFIT = {"friction": "--only {},friction", "inertia/payload": "--only {},armature", "delay": "--params delay"}


def residual_alarms(rows: Iterable[object]) -> list[dict]:
    """The alarms carried by cycle rows (mappings or objects with an ``outcome``), in cycle order, each with
    what its re-fit depends on: ``payload`` (the monitor's model has a payload signature) and ``stand`` (the
    robot stands on its feet: its row has gait features)."""
    out = []
    for row in rows:
        get = row.get if isinstance(row, Mapping) else (lambda k: getattr(row, k, None))
        outcome = get("outcome")
        residual = outcome.get("residual") if isinstance(outcome, Mapping) else None
        if isinstance(residual, Mapping):
            features = get("features") if isinstance(get("features"), Mapping) else {}
            cell = {"payload": "payload" in (residual.get("signatures") or ()),
                    "stand": any(kind_of(n).family == "gait" for n in features)}
            out += [{**a, **cell, "cycle": get("cycle")} for a in residual.get("alarms") or []
                    if isinstance(a, Mapping)]
    return sorted(out, key=lambda a: (a["cycle"] is None, a["cycle"] or 0))


def with_residual(findings: list[Finding], alarms: list[dict]) -> list[Finding]:
    """``findings`` with each alarm added as evidence to a matching one, told in the policy latency it arrived
    with (``_stale_plan``), or as a ``model_drift`` finding."""
    findings = list(findings)
    stale: dict[int, list[dict]] = {}  # per latency finding (its place in findings), the alarms that came with it
    for a in alarms:
        words = f"residual monitor, cycle {a['cycle']}: {a.get('message', a['parameter'])}"
        match = next((i for i, f in enumerate(findings) if a["joint"] in f.joints
                      and f.cause in MATCHES.get(a["parameter"], ())), None)
        late = next((i for i, f in enumerate(findings) if f.cause == "policy_latency" and a["cycle"] is not None
                     and abs(a["cycle"] - f.cycle) <= CONCURRENT), None)
        if match is not None:
            f = findings[match]
            signal = f"residual.{a['joint']}.{a['signature']}"
            findings[match] = Finding(f.cause, f.cycle, f.confidence,
                                      f.evidence + (words + WHY.get((a["parameter"], f.cause), ""),),
                                      f.signals + (signal,), f.joints, f.rate, f.legs)
        elif late is not None:
            stale.setdefault(late, []).append(a)
        else:
            findings.append(Finding("model_drift", int(a["cycle"] or 0), CONFIDENCE, (
                words, f"likely parameter: {a['parameter']}; {_refit(a)} re-fits it (a run record is 50 Hz between "
                       "events)"), (f"residual.{a['joint']}.{a['signature']}",), (a["joint"],)))
    return [_stale_plan(f, stale[i]) if i in stale else f for i, f in enumerate(findings)]


def _stale_plan(late: Finding, alarms: list[dict]) -> Finding:
    """The policy latency finding ``late`` with the residual ``alarms`` that arrived with it (within ``CONCURRENT``
    cycles) told in it: the joints move to the stale plan, against loads the joint model does not hold (a leg's
    foot forces), so the model's torque no longer fits them; not a drift of the model (a drive that changed
    at the same cycle would read the same)."""
    kinds = sorted({a["parameter"] for a in alarms})
    note = (f"also the residual monitor from cycle {min(a['cycle'] for a in alarms)} at "
            f"{', '.join(a['joint'] for a in alarms)} ({'-, '.join(kinds)}-like): the joints move to the stale plan, "
            "against loads the model does not hold, not a drift of the model (check these joints once the latency "
            "is fixed)",)
    return told(late, note, [f"residual.{a['joint']}.{a['signature']}" for a in alarms])


def _refit(alarm: dict) -> str:
    """The calls that re-fit ``alarm``'s likely parameter on its cell: an excitation record (on a stand for a
    robot on its feet, whose free base ``identify`` cannot fit from), then ``identify`` of that parameter (payload
    offered only where the monitor's model has one; a hand-made alarm is taken for an arm's)."""
    refit = REFIT.get(alarm["parameter"], "--params {}").format(alarm["joint"])
    if alarm["parameter"] == "inertia/payload" and alarm.get("payload", True):
        refit += " (or --params payload)"
    stand = " --stand" if alarm.get("stand") else ""
    return f"`cellguard excite CELL{stand} --seconds 20 --out DIR`, then `cellguard identify DIR {refit}`"
