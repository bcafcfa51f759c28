"""The lock a run holds on its folder while it writes its record there.

``run --overwrite`` into a folder whose run was still writing truncated that record in place and then wrote
beside its writer: both runs ended 0 and neither record was readable. The lock is an ``flock`` on the folder
itself (no file is added to it), taken before anything is written there and shared with the forked writer
process, so it holds until the last of them ends, the writer finishing a file after the loop's process died
included, and the kernel lets go of it when they are gone (no stale lock after a crash). Readers look at it
(``holder``) to tell a record still being written from a truncated one, and a file made from a record is written
beside it under the lock, held a moment (``record.beside``), so a run's start waits that long (``BRIEF_S``) before it
refuses. Each caller says how long it waits: a staging folder held is a live export's or recovery's, held for its
whole life, and is refused at once (waiting ``BRIEF_S`` there only delayed the refusal by a second).
"""

from __future__ import annotations

import fcntl
import os
import time
from pathlib import Path

from cellguard.errors import RecordError
from cellguard.output import UNLOCKABLE


BRIEF_S = 1.0  # how long a hold waits for another: a write beside a record holds the folder for a moment only
_HELD: dict[int, tuple[int, int]] = {}  # this process's holds: descriptor -> the folder's (st_dev, st_ino)


class Busy(RecordError):
    """Another process holds the folder; ``by``: who, as " (pid N)" where the kernel says, else ""."""

    def __init__(self, message: str, by: str):
        super().__init__(message)
        self.by = by


def hold(folder: Path, what: str = "--out", *, wait_s: float = BRIEF_S) -> int | None:
    """Lock ``folder`` (it must exist) for this process and the processes it forks; the descriptor that holds it
    (``release`` lets go), None on a filesystem that offers no locks. ``Busy`` naming the folder and its holder's pid
    if another process holds it for more than ``wait_s``: a reader's write beside a record is waited on (``BRIEF_S``:
    a run starting then is not refused for it), a recovery's short move too (``MOVE_WAIT_S``), a run's whole life is
    not (a recovery blocked silently for as long as a run that had started in its target), nor a staging folder's
    (``wait_s=0``)."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise RecordError(f"{what} {folder}: cannot be opened ({exc.strerror or exc})") from None
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            _HELD[fd] = identity(os.fstat(fd))
            return fd
        except BlockingIOError:
            if time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            by = _pid_words(_locker(os.fstat(fd)) or 0)
            os.close(fd)
            raise Busy(f"{what} {folder}: another run is still writing its record there{by}; nothing was touched: "
                       f"wait for it to end or choose another folder", by) from None
        except OSError as exc:
            os.close(fd)
            if exc.errno in UNLOCKABLE:  # a filesystem without locks (some network mounts): goes on unguarded
                return None
            raise RecordError(f"{what} {folder}: cannot be locked ({exc.strerror or exc})") from None


def held_here(folder: Path) -> bool:
    """Whether this process holds ``folder``'s lock already (``hold``): the demo writes its report under its own."""
    try:
        return identity(os.stat(folder)) in _HELD.values()
    except OSError:
        return False


def holder(folder: Path) -> str | None:
    """"a running process (pid N)" while a process holds ``folder``'s lock, else None, also where the folder cannot
    be read. Read from the kernel's list of locks (Linux: ``/proc/locks``), which takes no lock: a probe by a shared
    lock of its own, briefly held, refused a run starting that instant (11 of 20,000 starts beside a reader polling
    the folder). Only where there is no such list is the lock probed so. A record read while its run wrote it was
    told as truncated."""
    try:
        listed = _locker(os.stat(folder))
    except OSError:
        return None
    if listed is not False:
        return None if listed is None else f"a running process{_pid_words(listed)}"
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return None
    except BlockingIOError:
        return "a running process"
    except OSError:
        return None
    finally:
        os.close(fd)  # and with it a shared lock taken


def _locker(stat: os.stat_result) -> int | None | bool:
    """The pid of who holds the exclusive flock on the file of ``stat`` as ``/proc/locks`` lists it (0 there for a
    process in another pid namespace), None if no one; False where there is no list."""
    where = f"{os.major(stat.st_dev):02x}:{os.minor(stat.st_dev):02x}:{stat.st_ino}"
    try:
        with open("/proc/locks") as f:
            lines = f.read().splitlines()
    except OSError:
        return False
    for line in lines:  # "1: FLOCK  ADVISORY  WRITE 14908 fe:00:3171386 0 EOF"; a waiter's line has "->" second
        fields = line.split()
        if fields[1:4] == ["FLOCK", "ADVISORY", "WRITE"] and fields[5:6] == [where] and fields[4].isdigit():
            return int(fields[4])
    return None


def _pid_words(pid: int) -> str:
    """" (pid N)", or "" for pid 0 (a process in another pid namespace, or none known)."""
    return f" (pid {pid})" if pid else ""


def identity(stat: os.stat_result) -> tuple[int, int]:
    """A file's identity: (device, inode)."""
    return stat.st_dev, stat.st_ino


def release(fd: int | None) -> None:
    if fd is not None:
        _HELD.pop(fd, None)
        try:
            os.close(fd)
        except OSError:
            pass
