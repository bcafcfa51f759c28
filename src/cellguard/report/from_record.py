"""Write the report of a record folder: diagnosis from the record, overlay from its ticks."""

from __future__ import annotations

from pathlib import Path

from cellguard.diagnose.diagnosis import Diagnosis
from cellguard.diagnose.from_record import diagnose_record, run_folder
from cellguard.errors import RecordError
from cellguard.output import write_output
from cellguard.record.beside import Pin, guarded, pinned
from cellguard.report.html import render_report

REPORT_FILE = "report.html"


def write_report(folder: Path, out: Path | None = None, diagnosis: Diagnosis | None = None,
                 health=None, pin: Pin | None = None) -> Path:
    """Diagnose ``folder`` (a run folder or its record.mcap; unless ``diagnosis`` is given) and write the
    HTML, by default to the run folder's report.html; return its path. ``health``: the record's (``rec.health()``,
    read here if not given); a record that is not whole says so at the top of the page. ``pin``: the record pinned
    before ``diagnosis`` was read (``record.beside``): a page in its run folder is written only while the folder
    still holds that record, else RecordError and nothing written."""
    folder = Path(folder)
    out = Path(out) if out is not None else report_path(folder)
    with pinned(folder, "reported", pin) as held:
        page = _page(folder, diagnosis if diagnosis is not None else diagnose_record(folder, pin=held), health)
        with guarded(held, out, "reported"):
            return write_output(out, page, "report")


def _page(folder: Path, d: Diagnosis, health) -> str:
    """The report's HTML: the diagnosis ``d`` with the record's ticks overlaid."""
    from cellguard.record.reader import open_record

    with open_record(folder) as rec:

        def trace(cycle: int) -> dict | None:
            ticks = rec.ticks(cycle=cycle)
            if len(ticks) == 0:
                return None
            return {"t": (ticks.t_ns - ticks.t_ns[0]) * 1e-9, "current": ticks.current,
                    "error": ticks.q_cmd - ticks.q_meas, "joints": list(ticks.joints)}

        health = health if health is not None else rec.health()
        return render_report(d, trace, None if health.ok and not health.recovered else health.describe())


def report_path(record: Path) -> Path:
    """Where the report of ``record`` (a run folder or its record.mcap) goes by default: the run folder's
    report.html. RecordError for a loose .mcap file, which has no run folder to write into."""
    record = Path(record)
    home = run_folder(record)
    if home is None and record.exists():
        raise RecordError(f"{record}: is a record file outside a run folder; name the page to write with -o FILE")
    return (home or record) / REPORT_FILE


__all__ = ["REPORT_FILE", "report_path", "write_report"]
