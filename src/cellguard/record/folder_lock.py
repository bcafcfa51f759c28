"""The lock a run holds on its folder while it writes its record there.

``run --overwrite`` into a folder whose run was still writing truncated that record in place and then wrote
beside its writer: both runs ended 0 and neither record was readable. The lock is an ``flock`` on the folder
itself (no file is added to it), taken before anything is written there and shared with the forked writer
process, so it holds until the last of them ends, the writer finishing a file after the loop's process died
included, and the kernel lets go of it when they are gone (no stale lock after a crash).
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import time
from collections.abc import Iterable
from pathlib import Path

from cellguard.errors import RecordError


UNLOCKABLE = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL)  # flock is not offered there


def hold(folder: Path, what: str = "--out", wait_s: float = 0.0) -> int | None:
    """Lock ``folder`` (it must exist) for this process and the processes it forks; the descriptor that holds it
    (``release`` lets go), None on a filesystem that offers no locks. RecordError naming the folder if another
    process holds it for more than ``wait_s`` (a recovery's short move waits; a run's whole life is not waited on:
    a recovery blocked silently for as long as a run that had started in its target)."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise RecordError(f"{what} {folder}: cannot be opened ({exc.strerror or exc})") from None
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            if time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            os.close(fd)
            raise RecordError(f"{what} {folder}: another run is still writing its record there; nothing was touched: "
                              f"wait for it to end or choose another folder") from None
        except OSError as exc:
            os.close(fd)
            if exc.errno in UNLOCKABLE:  # a filesystem without locks (some network mounts): goes on unguarded
                return None
            raise RecordError(f"{what} {folder}: cannot be locked ({exc.strerror or exc})") from None


def release(fd: int | None) -> None:
    if fd is not None:
        try:
            os.close(fd)
        except OSError:
            pass


def clear_stale(staging: Iterable[Path], busy: str) -> None:
    """Remove the staging folders of commands killed before their clean-up (SIGKILL: nothing holds their lock, and
    each stayed for good); RecordError ``busy`` (naming the folder) if one is still held by a live command."""
    for old in staging:
        try:
            lock = hold(old, "-o")
        except RecordError:
            raise RecordError(f"{busy} ({old.name}); wait for it to end or give another folder") from None
        try:
            shutil.rmtree(old, ignore_errors=True)
        finally:
            release(lock)
