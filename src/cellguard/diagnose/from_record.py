"""Diagnose a record folder: read it through the record reader, keep its baseline beside it.

Reads the record only (``record.mcap`` via ``cellguard.record.reader``); never the run's
summary, whose ground truth holds the injected faults.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from cellguard.diagnose.baseline import METHOD, OWN_SOURCE, Baseline, TooFewCycles, check_same_robot
from cellguard.diagnose.cycles import as_cycles
from cellguard.diagnose.diagnosis import Diagnosis, diagnose
from cellguard.diagnose.recovery import acceptance_attempts, policy_cycles
from cellguard.diagnose.site_history import FIXES_FILE, save_fixes, site_history
from cellguard.embodiment.profile import SymmetryPair
from cellguard.errors import CellguardError, OutputError, RecordError
from cellguard.record.beside import Pin, guarded, pinned
from cellguard.record.folder_lock import Busy

BASELINE_FILE = "baseline.json"


def diagnose_record(path: Path, acceptance: Path | None = None, fleet: list[dict] | tuple = (),
                    unkept: list[str] | None = None, pin: Pin | None = None) -> Diagnosis:
    """Diagnose the record at ``path`` (a run folder, or its record.mcap); the baseline comes from
    ``acceptance`` (another record of the same robot and profile) if given, else from
    ``folder/baseline.json``, else from the record's acceptance cycles, and is then written to
    ``folder/baseline.json``. A baseline from another robot, profile or record, or one that cannot
    watch this record's features and motions, is refused. Advice comes from the site's other
    diagnosed records beside it and from ``fleet`` (rows of ``cellguard.fleet.advice.fleet_fixes``);
    what fixed each cause here is written to ``folder/fixes.json``. Neither is rewritten unchanged; where ``folder``
    cannot be written (a record on read-only storage), each that fails adds its line to ``unkept`` and the diagnosis
    stands (OutputError where no list is given). A loose .mcap file outside a run folder is diagnosed against its own
    acceptance cycles and nothing is written beside it; nor beside a record its run is still writing, nor beside a
    record that replaced it meanwhile (RecordError, ``record.beside``; ``pin``: the caller's, taken before it read)."""
    with pinned(path, "diagnosed", pin) as held:
        return _diagnosed(path, acceptance, fleet, unkept, held)


def _diagnosed(path: Path, acceptance: Path | None, fleet: list[dict] | tuple, unkept: list[str] | None,
               pin: Pin) -> Diagnosis:
    from cellguard.record.reader import open_record

    folder = run_folder(path)
    with open_record(path) as rec:
        cycles, events = list(rec.cycles()), list(rec.events())
        context = {**rec.context, "record_id": rec.record_id, "start_utc": rec.start_utc, "start_ns": rec.start_ns}
        bound = {**context, "epoch_wall_ns": rec.epoch_wall_ns}  # what a baseline of it is bound to
        writing = rec.writing  # a run still writes it: nothing is kept beside it, it would describe a part
        declared = rec.contexts[-1].context.get("process", [])  # process changes declared up to the end
    baseline, reference, unchecked = None, (), None
    if acceptance is not None:
        with open_record(acceptance) as acc:
            accepted = list(acc.cycles())
            rows = [c for c in as_cycles(accepted) if c.phase == "acceptance"]
            reference = acceptance_attempts(accepted)  # its recoveries' arrivals: the recovery reference
            acc_context = {**acc.context, "record_id": acc.record_id}
        check_same_robot(acc_context, context, f"--acceptance {acceptance}", path)
        _has_cycles(cycles, path)
        try:
            baseline = Baseline.from_cycles(policy_cycles(rows), source=f"acceptance cycles of {acceptance}"
                                            ).bind(acc_context)  # as the record's own baseline sees them
        except RecordError as exc:  # too few acceptance cycles there: say which record
            raise RecordError(f"--acceptance {acceptance}: {exc}") from None
        baseline.check_fits(as_cycles(cycles), f"--acceptance {acceptance}")
    elif folder is not None and (folder / BASELINE_FILE).is_file():
        baseline = Baseline.load(folder / BASELINE_FILE)
        baseline.check_binding(bound, folder / BASELINE_FILE)
        if baseline.unbound_epoch(bound):  # a format-1 record's, from before baselines named its epoch: taken
            unchecked, baseline = baseline, None  # again from its acceptance, kept only where the same (and rebound)
        elif baseline.method < METHOD and baseline.source == OWN_SOURCE:  # an earlier version's, from this record:
            baseline = None  # taken again from its acceptance cycles and written again (its scales read too low)
        else:
            baseline.check_fits(as_cycles(cycles), folder / BASELINE_FILE)
    past = site_history(folder, context.get("site"), context.get("record_id")) if folder is not None else []
    try:
        result = diagnose(cycles, events, {**context, "process": declared}, baseline=baseline,
                          symmetry=symmetry_of(context), history=[*past, *fleet], reference=reference)
    except TooFewCycles as exc:  # too few acceptance cycles, no production: say which record
        if unchecked is not None and exc.baseline:
            raise _not_its_own(folder / BASELINE_FILE) from None
        raise TooFewCycles(f"{path}: {exc}", exc.baseline) from None
    except RecordError as exc:
        raise RecordError(f"{path}: {exc}") from None
    if unchecked is not None and not unchecked.same_acceptance(result.baseline):
        raise _not_its_own(folder / BASELINE_FILE)
    if baseline is None:  # as a stored baseline is judged when read again, so the first diagnosis agrees
        result.baseline.check_fits(as_cycles(cycles), f"{path} (its own acceptance cycles)")
    if baseline is None and folder is not None and not writing:  # first: a baseline.json refused (a FIFO there) leaves nothing
        _keep(lambda: result.baseline.bind(bound).save(folder / BASELINE_FILE), folder / BASELINE_FILE, pin, unkept)
    if folder is not None and not writing:
        _keep(lambda: save_fixes(folder, context, result.fixes), folder / FIXES_FILE, pin, unkept)
    return result


def _not_its_own(path: Path) -> RecordError:
    """The refusal of a baseline at ``path`` that names no epoch (written before baselines of format-1 records were
    bound) and that was not taken from the record's own acceptance cycles: another run's, copied beside it."""
    return RecordError(f"{path}: baseline is not this record's: it names no epoch_wall_ns and was not taken "
                       "from this record's acceptance cycles; delete it to rebuild it from them, or pass "
                       "--acceptance DIR")


def _has_cycles(cycles: list, path: Path) -> None:
    """RecordError where the record has no finished cycle (its run ended in its first), said before another record's
    baseline is judged against it: every feature of the baseline is missing from a record of none, which read as a
    baseline of another cell."""
    if not cycles:
        raise TooFewCycles(f"{path}: the record has no finished cycle to diagnose")


def _keep(save: Callable[[], object], target: Path, pin: Pin, unkept: list[str] | None) -> None:
    """Run ``save``, which writes ``target`` beside the record (made again from the record when missing), only while
    the folder still holds the record read (``record.beside``). Where the folder cannot be written (read-only storage:
    an archive), its OutputError goes to ``unkept`` if a list is given: the diagnosis is whole without the file. Any
    other refusal (a FIFO or a record where it goes) ends it; so does another process holding the folder where no
    list is given."""
    try:
        with guarded(pin, target, "diagnosed"):
            save()
    except (OutputError, Busy) as exc:  # Busy: another process writes there now (the demo its report); the
        # diagnosis of the record pinned stands (a fleet push stopped at the first such run folder)
        if unkept is None or (isinstance(exc, OutputError) and os.access(target.parent, os.W_OK)):
            raise
        unkept.append(str(exc))


def run_folder(path: Path) -> Path | None:
    """The run folder of a record: ``path`` itself if a folder, the folder of a ``record.mcap``; None
    for a loose .mcap file (nothing of the record's is kept beside it). RecordError naming ``path`` if it cannot be
    looked at (a component over 255 bytes, no access), where is_dir raises OSError."""
    from cellguard.record.writer import RECORD_FILE

    path = Path(path)
    try:
        if path.is_dir():
            return path
        return path.parent if path.name == RECORD_FILE and path.is_file() else None
    except OSError as exc:
        raise RecordError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def symmetry_of(context: dict) -> tuple[SymmetryPair, ...]:
    """The symmetry map of the record's cell, from its registered embodiment profile."""
    from cellguard.robot.registry import make_cell

    try:
        return make_cell(str(context.get("cell", ""))).profile.symmetry
    except CellguardError:
        return ()
