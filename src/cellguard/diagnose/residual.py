"""The residual monitor's alarms as diagnosis input: evidence on a matching finding, else ``model_drift``.

A run watched by ``calibrate.residual`` carries, in each cycle's outcome, ``residual.alarms``: the
joint whose measured torque left its model and the likely parameter. A finding that already names
that joint with a matching cause (``friction`` for a friction-like residual; ``servo`` for an
inertia-like one, a weaker servo's changed motion) gains the alarm as evidence; otherwise the alarm
becomes a ``model_drift`` finding of its own.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from cellguard.diagnose.cause import Finding

# A weaker servo moves its joint otherwise (it lags, accelerates later): the residual of the model over that
# motion then shifts along the acceleration, read as inertia-like, with no change of the arm's mass.
MATCHES = {"friction": ("friction",), "inertia/payload": ("tool_slip", "part_misplaced", "servo"), "delay": ("servo",)}
WHY = {("inertia/payload", "servo"): " (the weaker servo moves the joint otherwise; the model reads that as inertia)"}
CONFIDENCE = 0.7
REFIT = {"friction": "--only {},friction", "inertia/payload": "--only {},armature (or --params payload)",
         "delay": "--params delay"}  # what to re-fit, per likely parameter ({} the joint)


def residual_alarms(rows: Iterable[object]) -> list[dict]:
    """The alarms carried by cycle rows (mappings or objects with an ``outcome``), in cycle order."""
    out = []
    for row in rows:
        outcome = row.get("outcome") if isinstance(row, Mapping) else getattr(row, "outcome", None)
        residual = outcome.get("residual") if isinstance(outcome, Mapping) else None
        if isinstance(residual, Mapping):
            cycle = row.get("cycle") if isinstance(row, Mapping) else getattr(row, "cycle", None)
            out += [{**a, "cycle": cycle} for a in residual.get("alarms") or [] if isinstance(a, Mapping)]
    return sorted(out, key=lambda a: (a["cycle"] is None, a["cycle"] or 0))


def with_residual(findings: list[Finding], alarms: list[dict]) -> list[Finding]:
    """``findings`` with each alarm added as evidence to a matching one, or as a ``model_drift`` finding."""
    findings = list(findings)
    for a in alarms:
        words = f"residual monitor, cycle {a['cycle']}: {a.get('message', a['parameter'])}"
        match = next((i for i, f in enumerate(findings) if a["joint"] in f.joints
                      and f.cause in MATCHES.get(a["parameter"], ())), None)
        if match is not None:
            f = findings[match]
            signal = f"residual.{a['joint']}.{a['signature']}"
            findings[match] = Finding(f.cause, f.cycle, f.confidence,
                                      f.evidence + (words + WHY.get((a["parameter"], f.cause), ""),),
                                      f.signals + (signal,), f.joints, f.rate, f.legs)
            continue
        refit = REFIT.get(a["parameter"], "--params {}").format(a["joint"])
        findings.append(Finding("model_drift", int(a["cycle"] or 0), CONFIDENCE, (
            words, f"likely parameter: {a['parameter']}; `cellguard excite CELL --seconds 20 --out DIR`, then "
                   f"`cellguard identify DIR {refit}` re-fits it (a run record is 50 Hz between events)"),
            (f"residual.{a['joint']}.{a['signature']}",), (a["joint"],)))
    return findings
