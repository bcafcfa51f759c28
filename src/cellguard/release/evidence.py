"""The evidence of a stage: its runs' records, read once through the record reader.

A run folder holds ``record.mcap`` (read with ``cellguard.record.reader``) and, for a pilot run in
shadow mode, ``shadow.json`` (per chunk: distance to the incumbent, would-clamp, would-stop). A
counted run is read only as the record that was counted: hashed again, its context naming the
release, cell and stage that counted it, and its shadow rows only as the file counted with it
(hashed again; a row an older cellguard counted holds no hash: its file is read as found). Its
chunks and ticks are kept reduced (``reductions``).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from cellguard.errors import CellguardError, RecordError
from cellguard.record.json_values import loads
from cellguard.record.reader import CycleRecord, EventRecord, open_record
from cellguard.record.writer import RECORD_FILE
from cellguard.release.bundle import canonical_json, sha256_file
from cellguard.release.errors import ReleaseError
from cellguard.release.reductions import Chunks, LimitTicks, limit_ticks, reduce_chunks
from cellguard.release.store import RunRow, Store
from cellguard.robot.registry import make_cell

SHADOW_FILE = "shadow.json"


@dataclass(frozen=True)
class RunEvidence:
    """One run as the gates see it; ``record_id`` names it in the log and on the release page."""

    record_id: str
    name: str
    folder: str
    context: dict
    cycles: tuple[CycleRecord, ...]
    events: tuple[EventRecord, ...]
    chunks: Chunks
    limits: LimitTicks  # its recorded (decimated) ticks outside the profile's limits
    shadow: tuple[dict, ...] | None  # per candidate chunk, or None when the run had no shadow
    shadow_sha256: str | None = None  # the sha256 of the shadow file read
    record_sha256: str | None = None  # the whole sha256 of the record file read (``record_id`` is its start)
    # ``once``'s figures by name; not an argument: a copy with other cycles (``dataclasses.replace``) derives its own
    derived: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    def label(self, cycle: int | None = None) -> str:
        return f"record {self.record_id} ({self.name})" + (f" cycle {cycle}" if cycle is not None else "")

    def once(self, name: str, compute: Callable[[RunEvidence], object]):
        """``compute(self)`` as JSON values, computed once per record: kept with the run's evidence (``kept``), a
        figure a metric derives from this run alone (its diagnosis) is not derived again at every evaluation that
        counts the run. Read back through JSON the first time too, so it is the same value every time."""
        if name not in self.derived:
            self.derived[name] = loads(canonical_json(compute(self)))
        return self.derived[name]


def record_id(folder: Path) -> str:
    """A record's id: the first 16 hex characters of its file's sha256 (content-addressed)."""
    return sha256_file(Path(folder) / RECORD_FILE, "record")[:16]


def load_run(folder: Path, name: str) -> RunEvidence:
    """The run in ``folder``, its id hashed from the record file read, and its shadow's from the bytes parsed (never
    taken from elsewhere)."""
    folder = Path(folder)
    with open_record(folder) as rec:
        context = rec.context
        cycles, events, chunks = tuple(rec.cycles()), tuple(rec.events()), reduce_chunks(rec.chunks())
        ticks = rec.ticks(rate="decimated")
        limits = limit_ticks(ticks, make_cell(str(context.get("cell"))).profile) if len(ticks) else LimitTicks()
        whole = rec.sha256()  # of the bytes read (hashed from its path, another record's evidence was kept under it)
    shadow, digest = _shadow(folder / SHADOW_FILE)
    return RunEvidence(whole[:16], name, str(folder), context, cycles, events, chunks, limits, shadow, digest, whole)


def _shadow(path: Path) -> tuple[tuple[dict, ...] | None, str | None]:
    """(its chunks, the sha256 of the bytes read), or (None, None) when there is no such file; RecordError when it
    cannot be read or holds no list of chunks (a damaged file was a traceback)."""
    if not path.is_file():
        return None, None
    try:
        data = path.read_bytes()
        chunks = loads(data)["chunks"]
    except OSError as exc:
        raise RecordError(f"{path}: cannot read ({exc.strerror or exc.__class__.__name__})") from None
    except (ValueError, TypeError, KeyError):
        chunks = None
    if not isinstance(chunks, list) or not all(isinstance(c, dict) for c in chunks):
        raise RecordError(f"{path}: not a shadow record (a JSON object with a list of chunks)")
    return tuple(chunks), hashlib.sha256(data).hexdigest()


def counted_run(store: Store, row: RunRow, read: Callable[[Path, str], RunEvidence] = load_run) -> RunEvidence:
    """``row``'s run as evidence; ReleaseError naming its folder unless it is the record that was counted (same
    hash) and its context names the row's release, cell and stage, nor with other shadow rows than those counted
    with it (``row.shadow``): a record put in its place, even one that passed for another release, is never read as
    this run, and an edited shadow file never turns its candidate's verdict (an evaluation gives ``row.shadow`` the
    hash the log signed, ``log.counted_shadows``: a file edited with its row is refused too). ``read``: how the run
    is read (``load_run``, or ``kept.Kept.read``: its evidence as kept when read before)."""
    folder = store.run_folder(row)
    try:
        run = read(folder, row.name)
    except CellguardError as exc:
        raise ReleaseError(f"run {row.name!r} ({row.record_id}): {exc}") from None
    if run.record_id != row.record_id:
        raise ReleaseError(f"{folder}: holds record {run.record_id}, not {row.record_id} that was counted as run "
                           f"{row.name!r} (replaced since)")
    if row.shadow is not None and run.shadow_sha256 != row.shadow:
        now = f"hashes to {run.shadow_sha256[:16]}" if run.shadow_sha256 else "is gone"
        raise ReleaseError(f"{folder}: its {SHADOW_FILE} {now}, not {row.shadow[:16]} as counted with run "
                           f"{row.name!r} (edited since)")
    bound = run.context.get("release") if isinstance(run.context, dict) else None
    got = tuple(bound.get(k) for k in ("id", "cell", "stage")) if isinstance(bound, dict) else (None,) * 3
    if got != (row.release, row.cell, row.stage):
        raise ReleaseError(f"{folder}: its record is a run of release {got[0]} at {got[2]} on {got[1]}, not of "
                           f"{row.release} at {row.stage} on {row.cell}")
    return run
