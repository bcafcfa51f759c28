"""The files made from a record, set aside while ``run --overwrite`` puts a new record in their folder.

The old record's index parts and the files made from it (summary, baseline, report, replay pages) must not stay
beside the new record (an old baseline made the new run's diagnosis refuse it), nor go before the new record is in
place: removed first, a SIGKILL before the rename left the old record with an empty ``index/`` and no summary or
report, and a rename that failed lost them while saying "nothing was run". So ``Recorder.place`` moves them (renames,
on the run folder's filesystem) into one hidden folder, ``ASIDE``, having noted there which files and the identity of
the record they were made from, renames the new record into place, then removes that folder; a failure before the
rename moves them back. A start killed in between leaves the folder: the next start in that run folder (``settle``,
under its lock) moves them back if the record there is still theirs, else removes them (the new record took its
place). No reader looks there: the index is read from ``index/`` only, and the folder never holds a record file.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path, PurePosixPath

from cellguard.record import folder_lock

ASIDE = ".record.mcap.replaced"
NOTE = "note.json"  # in ASIDE, written before any move: {"record": its identity or null, "files": [relative paths]}


@contextlib.contextmanager
def aside(folder: Path, record: Path, files: list[str]) -> Iterator[None]:
    """Move ``files`` (relative to ``folder``, made from ``record``) into ``folder / ASIDE`` for the body (which puts
    the new record at ``record``), then remove them; if the body or a move fails, they are moved back (or, where that
    fails too, left in ``ASIDE`` for the next start's ``settle``) and the error goes on."""
    store = folder / ASIDE
    store.mkdir()  # ``settle`` removed anything there
    try:
        (store / NOTE).write_text(json.dumps({"record": _identity(record), "files": files}))
        for name in files:
            (store / name).parent.mkdir(parents=True, exist_ok=True)
            os.rename(folder / name, store / name)
        yield
    except BaseException:
        put_back(folder)
        raise
    shutil.rmtree(store, ignore_errors=True)  # a part left: ``settle`` removes it (not this record's)


def settle(folder: Path, record: Path) -> bool:
    """Clear what a start killed while placing its record left in ``folder``: the files it set aside are put back if
    ``record`` is still the one they were made from, else removed. Whether they were theirs (put back, all or some:
    the folder must be checked again)."""
    store = folder / ASIDE
    if not os.path.lexists(store):
        return False
    note = _note(store) if store.is_dir() and not store.is_symlink() else None
    if note is not None and note["record"] == _identity(record):
        put_back(folder)
        return True
    with contextlib.suppress(OSError):  # a file or link of this name is no one's: the name is cellguard's
        if store.is_dir() and not store.is_symlink():
            shutil.rmtree(store)
        else:
            store.unlink()
    return False


def put_back(folder: Path) -> bool:
    """Move the files noted in ``folder / ASIDE`` back to their places and remove it; a file at its place now (made
    since from the same record: a report) stays, and the one set aside goes. False, ``ASIDE`` left, if a move failed."""
    store = folder / ASIDE
    note = _note(store)
    try:
        for name in note["files"] if note is not None else []:  # no note: nothing was moved
            if os.path.lexists(store / name) and not os.path.lexists(folder / name):
                (folder / name).parent.mkdir(parents=True, exist_ok=True)
                os.rename(store / name, folder / name)
        shutil.rmtree(store)
    except OSError:
        return False
    return True


def _identity(record: Path) -> list[int] | None:
    """What tells the record at ``record`` from a later one: device, inode and size (a finished record is never
    written again; an inode alone is reused by the next file made), None where there is none."""
    try:
        st = os.lstat(record)
    except FileNotFoundError:
        return None
    return [*folder_lock.identity(st), st.st_size]


def _note(store: Path) -> dict | None:
    """``store``'s note; None if it cannot be read or names a file outside the run folder (damaged or crafted)."""
    try:
        note = json.loads((store / NOTE).read_text())
        files, record = note["files"], note["record"]
        names = [PurePosixPath(name) for name in files]
    except (OSError, ValueError, TypeError, KeyError, RecursionError):
        return None
    if not isinstance(files, list) or any(name.is_absolute() or ".." in name.parts or not name.parts
                                          or "\0" in str(name) for name in names):
        return None
    if record is not None and not (isinstance(record, list) and all(type(n) is int for n in record)):
        return None
    return note
