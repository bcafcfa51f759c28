"""A site's signatures from its run folders: each folder's whole record diagnosed, each finding one row.

Reads the record (``record.mcap``) through the diagnosis, never the run's summary (its ground
truth holds the injected faults). DIR is a run folder or a folder of run folders. The baseline
is each run's own acceptance cycles, or one acceptance run's (a cell commissioned once, its
production runs diagnosed against it).
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from cellguard.dates import utc_day, utc_today
from cellguard.errors import RecordError
from cellguard.fleet.export import AHEAD, newest_kept
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature, signatures_of

RECORD = "record.mcap"


def run_folders(folder: Path) -> list[Path]:
    folder = Path(folder)
    if (folder / RECORD).is_file():
        return [folder]
    found = sorted(p.parent for p in folder.glob(f"*/{RECORD}")) if folder.is_dir() else []
    if not found:
        raise RecordError(f"{folder}: no {RECORD} in it or in its sub-folders")
    return found


def site_signatures(folder: Path, policy: DataPolicy, acceptance: Path | None = None,
                    unkept: list[str] | None = None, skipped: list[str] | None = None,
                    stored: bool = True, copies: list[str] | None = None) -> list[Signature]:
    """Every finding of every whole run under ``folder``, as signatures of the policy's tenant and site;
    ``acceptance``: the record folder whose acceptance cycles are the baseline of every run; ``unkept``: as
    ``diagnose_record``'s (a run on read-only storage is pushed, the files its diagnosis keeps beside it named).
    A run whose record is not whole (truncated, damaged, or still being written) is not diagnosed: its findings
    would differ from the whole record's (another onset, another confidence: other signature ids), so pooled now
    they would be pooled again once it is whole. Nor, when the signatures are to be ``stored`` (a push; not the
    probes of ``fleet similar``, which the store keeps nowhere), is a run that started after tomorrow by this
    host's date (``export.newest_kept``): no export may send its findings with that date, nor one whose record was
    replaced while it was diagnosed (``record.beside``), nor one with too few cycles to diagnose (an excitation
    record: ``TooFewCycles``). Each is named in ``skipped``, one line each; with no list to name it in, RecordError.
    A record met again (its record id, or its file where it has none: a ``latest`` link, a backup copy) is diagnosed
    once: each folder holding it again is named in ``copies``."""
    from cellguard.diagnose.baseline import TooFewCycles
    from cellguard.diagnose.from_record import diagnose_record
    from cellguard.record.beside import Replaced
    from cellguard.record.reader import open_record

    out, newest, read = [], newest_kept(), set()
    for run in run_folders(folder):
        try:
            with open_record(run) as rec:
                epoch_ns = rec.start_wall_ns if rec.epoch_wall_ns else 0  # stated in the context messages too
                health = rec.health()
                same = rec.record_id or str(rec.file.resolve())
            day = utc_day(epoch_ns) if epoch_ns > 0 else utc_today()  # no epoch stated: the day of export
            problem = (_not_whole(run, health) if not health.ok
                       else _ahead(run, day, newest) if stored and day > newest else None)
        except RecordError as exc:  # not even opened: cut inside its first chunk, or a run only just begun
            problem = f"{exc}; its findings were left out"
        if problem is not None:
            if skipped is None:
                raise RecordError(problem)
            skipped.append(problem)
            continue
        if same in read:
            if copies is not None:
                copies.append(str(run))
            continue
        read.add(same)
        try:
            diagnosis = diagnose_record(run, acceptance=acceptance, unkept=unkept)
        except Replaced as exc:  # a run --overwrite replaced it meanwhile: the next push takes the new one
            if skipped is None:
                raise
            skipped.append(f"{exc}; its findings were left out")
            continue
        except TooFewCycles as exc:  # names the run and what it lacks (an excitation record's one cycle)
            if skipped is None or (exc.baseline and acceptance is not None):  # --acceptance's: every run's baseline
                raise
            skipped.append(f"{exc}; its findings were left out")
            continue
        out.extend(signatures_of(diagnosis.to_dict(), diagnosis.context, policy.tenant, policy.site, day))
    return out


def _not_whole(run: Path, health) -> str:
    """One line naming a run left out, what its record lacks and what makes it whole."""
    then = ("run the command again once its run has ended" if health.writing
            else f"`cellguard record recover {run} -o NEW_DIR` writes a finished copy" if health.recoverable
            else "only a whole record's findings are pooled")
    return f"{run}: {health.describe()}; its findings were left out: {then}"


def _ahead(run: Path, day: dt.date, newest: dt.date) -> str:
    """One line naming a run left out because it started after tomorrow (``newest``), and why."""
    return (f"{run}: its record started on {day}, after tomorrow ({newest}) by this host's UTC date (the clock that "
            f"recorded it ran ahead, or this host's is behind); its findings were left out: {AHEAD}")
