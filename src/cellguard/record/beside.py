"""Files made from a record and written beside it (report.html, baseline.json, fixes.json): only while its folder
still holds that record.

``run --overwrite`` replaced a folder's record while ``report`` was reading the old one: the old record's
report.html (once its baseline.json and fixes.json too) landed beside the new record, both commands ended 0, and the
next ``diagnose`` refused the stale baseline. A reader pins the record file before it reads it (``pinned``: the file
held open, so its inode is not freed and no new record takes its number) and writes beside it only under the folder's
lock (``folder_lock``: a run holds it for its whole life, from before it replaces a record), once record.mcap there is
still the pinned file (``guarded``). Otherwise nothing is written and RecordError says why.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from cellguard.errors import RecordError
from cellguard.record import folder_lock
from cellguard.record.reader import record_file
from cellguard.record.writer import RECORD_FILE


@dataclass(frozen=True)
class Pin:
    """A record file held open (``fd``; None if it could not be opened) and its run folder as given (``home``; None
    for a loose .mcap file, beside which nothing is written)."""

    fd: int | None
    home: Path | None


class Replaced(RecordError):
    """The record was replaced while it was being read: nothing made from it is written beside the new one."""


@contextlib.contextmanager
def pinned(path: Path, doing: str, pin: Pin | None = None) -> Iterator[Pin]:
    """The record of ``path`` (a run folder or its record.mcap) pinned while the block reads it and writes beside it;
    ``pin``: one the caller holds already, used as it is. Pinned before the first read: a record replaced after it
    is told by its inode. A RecordError in the block, once the record was replaced (a read of the new one half
    written, "got 0 acceptance cycles"), is ``Replaced`` (``doing``: what was done with it, "reported")."""
    if pin is not None:
        yield pin
        return
    file = record_file(path)
    try:  # a regular file only: opening a FIFO releases a writer blocked on it, a device may act on an open
        fd = os.open(file, os.O_RDONLY | os.O_NONBLOCK) if stat.S_ISREG(os.stat(file).st_mode) else None
    except OSError:  # the read says why; nothing is written beside it
        fd = None
    pin = Pin(fd, file.parent if file.name == RECORD_FILE else None)
    try:
        yield pin
    except Replaced:
        raise
    except RecordError:
        if fd is not None and pin.home is not None and _replaced(pin):
            raise Replaced(f"{pin.home}: its record was replaced while it was being {doing}; nothing written") from None
        raise
    finally:
        if fd is not None:
            os.close(fd)


@contextlib.contextmanager
def guarded(pin: Pin, target: Path, doing: str) -> Iterator[None]:
    """While the block writes ``target``, made from the record of ``pin``: if ``target`` goes into that record's run
    folder, hold the folder's lock (waiting ``folder_lock.BRIEF_S`` for another reader's write), and only if
    record.mcap there is still the pinned file; RecordError naming the folder and what was not written otherwise
    (``doing``: what was done with the record, "reported"; ``folder_lock.Busy`` where another process holds the
    folder). A target elsewhere (``report -o FILE``) is written unlocked, once the record is found not replaced.
    Where the folder cannot be locked at all, no run can hold it either: the file is checked, unlocked."""
    target = Path(target)
    if pin.home is None:
        yield
        return
    if not _same_folder(target.parent, pin.home):  # elsewhere: no lock, but never a page of a record replaced
        _refuse_if_replaced(pin, target, doing)  # (its charts were read from the new one, its text from the old)
        yield
        return
    lock = None
    if not folder_lock.held_here(pin.home):  # the demo writes its report under the lock of its own run
        try:
            lock = folder_lock.hold(pin.home, wait_s=folder_lock.BRIEF_S)
        except folder_lock.Busy as exc:
            _refuse_if_replaced(pin, target, doing)
            raise folder_lock.Busy(f"{pin.home}: another process is writing there now{exc.by}; {target.name} not "
                                   f"written: run it again once it has ended", exc.by) from None
        except RecordError:  # the folder cannot be locked (no access): checked below all the same
            pass
    try:
        _refuse_if_replaced(pin, target, doing)
        yield
    finally:
        folder_lock.release(lock)


def _refuse_if_replaced(pin: Pin, target: Path, doing: str) -> None:
    if pin.fd is None or _replaced(pin):
        raise Replaced(f"{pin.home}: its record was replaced while it was being {doing}; {target.name} not written")


def _replaced(pin: Pin) -> bool:
    """Whether the run folder of ``pin`` holds a record file other than the pinned one now, or none."""
    try:
        return folder_lock.identity(os.stat(pin.home / RECORD_FILE)) != folder_lock.identity(os.fstat(pin.fd))
    except OSError:  # removed meanwhile
        return True


def _same_folder(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them is gone: told by name
        return os.path.realpath(a) == os.path.realpath(b)
