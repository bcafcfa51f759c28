"""Diagnose a record folder: read it through the record reader, keep its baseline beside it.

Reads the record only (``record.mcap`` via ``cellguard.record.reader``); never the run's
summary, whose ground truth holds the injected faults.
"""

from __future__ import annotations

from pathlib import Path

from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cycles import as_cycles
from cellguard.diagnose.diagnosis import Diagnosis, diagnose
from cellguard.diagnose.site_history import save_fixes, site_history
from cellguard.embodiment.profile import SymmetryPair
from cellguard.errors import CellguardError

BASELINE_FILE = "baseline.json"


def diagnose_record(folder: Path, acceptance: Path | None = None, fleet: list[dict] | tuple = ()) -> Diagnosis:
    """Diagnose the record in ``folder``; the baseline comes from ``acceptance`` (another record
    folder) if given, else from ``folder/baseline.json``, else from the record's acceptance
    cycles, and is then written to ``folder/baseline.json``. Advice comes from the site's other
    diagnosed records beside it and from ``fleet`` (rows of ``cellguard.fleet.advice.fleet_fixes``);
    what fixed each cause here is written to ``folder/fixes.json``."""
    from cellguard.record.reader import open_record

    folder = Path(folder)
    with open_record(folder) as rec:
        cycles, events, context = list(rec.cycles()), list(rec.events()), {**rec.context, "record_id": rec.record_id}
        declared = rec.contexts[-1].context.get("process", [])  # process changes declared up to the end
    baseline = None
    if acceptance is not None:
        with open_record(acceptance) as acc:
            rows = [c for c in as_cycles(acc.cycles()) if c.phase == "acceptance"]
        baseline = Baseline.from_cycles(rows, source=f"acceptance cycles of {acceptance}")
    elif (folder / BASELINE_FILE).is_file():
        baseline = Baseline.load(folder / BASELINE_FILE)
        baseline.check_binding(context, folder / BASELINE_FILE)
    past = site_history(folder, context.get("site"))
    result = diagnose(cycles, events, {**context, "process": declared}, baseline=baseline,
                      symmetry=symmetry_of(context), history=[*past, *fleet])
    if folder.is_dir():
        save_fixes(folder, context, result.fixes)
    if baseline is None and folder.is_dir():
        result.baseline.bind(context).save(folder / BASELINE_FILE)
    return result


def symmetry_of(context: dict) -> tuple[SymmetryPair, ...]:
    """The symmetry map of the record's cell, from its registered embodiment profile."""
    from cellguard.robot.registry import make_cell

    try:
        return make_cell(str(context.get("cell", ""))).profile.symmetry
    except CellguardError:
        return ()
