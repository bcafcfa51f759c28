"""An output made in a staging folder and moved into its target in several moves, undone as a whole if cut short.

``to-lerobot`` and ``recover`` write into a staging folder of their own, locked while their process lives
(``folder_lock``), and then move its files into the target one part at a time (the target stays the same folder: it
may be a shell's current one). Killed (SIGKILL) between two moves, a run left a target holding some of the files: the
rerun refused it as not empty, and the user had to pick files out by hand. So before its first move a run notes in
its staging folder each file it holds with its identity (device, inode, size, mtime: a rename and a hard link keep
it; an inode alone is reused by the next file made). A run was cut short if a noted file is still in its staging
folder and not in the target. Whoever clears a killed run's staging folder then takes the noted files out of the
target, and the folders this leaves empty, but only if the target holds nothing else (no other file, no file changed,
no link, no other folder); otherwise, or where the note cannot be read, nothing is touched and the target is refused
as not empty. A target that got every file is a finished output and is kept as one, whatever was done to it since.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
from collections.abc import Callable, Iterable
from pathlib import Path, PurePosixPath

from cellguard.errors import RecordError
from cellguard.record import folder_lock

# in the staging folder, written before any move: [[relative path, device, inode, size, mtime_ns], ...]
NOTED = ".moved-files.json"
Identity = tuple[int, int, int, int]


def note_files(staging: Path) -> list[Path]:
    """Every file under ``staging`` (relative paths, sorted), noted with its identity in its ``NOTED`` file (flushed
    to disk before the first move: the moves may reach the disk before it otherwise)."""
    files = sorted(p.relative_to(staging) for p in staging.rglob("*") if p.is_file() and not p.is_symlink())
    noted = [[f.as_posix(), *_identity(os.lstat(staging / f))] for f in files]
    with open(staging / NOTED, "w") as out:
        json.dump(noted, out)
        out.flush()
        os.fsync(out.fileno())
    return files


def _nothing(entry: Path) -> bool:
    return False


def take_back(staging: Path, target: Path, beside: Callable[[Path], bool] = _nothing) -> bool:
    """Take out of ``target`` what a run cut short in its moves had moved there from ``staging`` (see the module);
    ``beside``: the entries of ``target`` that are no part of it (the staging folders in it). Whether ``target`` is
    left holding nothing of the run's or its finished output; False: refused, nothing touched."""
    if _holds_only(target, {}, beside):
        return True  # nothing was moved there
    noted = _read_note(staging)
    if noted is None:
        return False
    if not _cut_short(staging, target, noted) or not _moved(target, noted):
        return True  # a finished output, or nothing of the run's there (stopped before its first move)
    if not _holds_only(target, noted, beside):
        return False
    for name, identity in noted.items():
        with contextlib.suppress(OSError):
            _remove(target, name, identity)
    return True


def clear_killed(leftovers: Iterable[Path], target: Path, busy: str,
                 beside: Callable[[Path], bool] = _nothing) -> str:
    """Remove the staging folders of runs into ``target`` killed before their clean-up (no process holds their lock),
    once what they had moved into ``target`` is taken back (``take_back``); one whose take-back is refused is kept, so
    that its note still tells its files once the target holds nothing else. RecordError ``busy`` (naming the folder) if
    one is still held by a live run, whose folder and files are left as they are. Returns what the target's refusal as
    not empty says of the folders kept ("" for none): without it the user was not told what to remove."""
    kept = []
    for old in leftovers:
        try:
            lock = folder_lock.hold(old, "-o", wait_s=0)  # a live run holds it for its whole life: refused at once
        except RecordError:
            raise RecordError(f"{busy} ({old.name}); wait for it to end or give another folder") from None
        try:
            if take_back(old, target, beside):
                shutil.rmtree(old, ignore_errors=True)
            else:
                kept.append(str(old))
        finally:
            folder_lock.release(lock)
    return (f"a run stopped while moving its files into it left {', '.join(kept)} ({NOTED} there lists the files it "
            f"moved); that folder goes with the next run once the target is empty") if kept else ""


def _identity(st: os.stat_result) -> Identity:
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _read_note(staging: Path) -> dict[PurePosixPath, Identity] | None:
    """The noted files of ``staging`` by relative path; None if the note cannot be read, is not this user's (a folder
    of that name made by another user beside a target in /tmp), or holds anything but relative paths inside the
    target with four whole numbers each (a damaged or crafted note)."""
    try:
        with open(os.open(staging / NOTED, os.O_RDONLY | os.O_NOFOLLOW), "rb") as f:
            if {os.fstat(f.fileno()).st_uid, os.lstat(staging).st_uid} != {os.geteuid()}:
                return None
            entries = json.loads(f.read())
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(entries, list):
        return None
    noted = {}
    for entry in entries:
        if not (isinstance(entry, list) and len(entry) == 5 and isinstance(entry[0], str)
                and all(type(n) is int and n >= 0 for n in entry[1:])):
            return None
        name = PurePosixPath(entry[0])
        try:
            os.fsencode(entry[0])
        except UnicodeError:  # a lone surrogate: no file name
            return None
        if "\0" in entry[0] or name.is_absolute() or not name.parts or ".." in name.parts:
            return None
        noted[name] = tuple(entry[1:])
    return noted


def _cut_short(staging: Path, target: Path, noted: dict[PurePosixPath, Identity]) -> bool:
    """Whether a noted file is still in ``staging`` and not in ``target`` (a hard-linked move has it in both)."""
    return any(_at(staging / name) == identity and _at(target / name) != identity for name, identity in noted.items())


def _moved(target: Path, noted: dict[PurePosixPath, Identity]) -> bool:
    """Whether a noted file is in ``target`` with its identity."""
    return any(_at(target / name) == identity for name, identity in noted.items())


def _at(path: Path) -> Identity | None:
    try:
        return _identity(os.lstat(path))
    except OSError:
        return None


def _holds_only(target: Path, noted: dict[PurePosixPath, Identity], beside: Callable[[Path], bool]) -> bool:
    """Whether every entry under ``target`` (but those ``beside`` it at its top) is a noted regular file with its
    noted identity or a folder on the way to one. A link is never followed: one anywhere is an entry of another
    kind. A target that is not there holds nothing; one that cannot be read, something."""
    ways = {folder for name in noted for folder in name.parents}

    def only(folder: Path, relative: PurePosixPath) -> bool:
        with os.scandir(folder) as entries:
            for entry in entries:
                name = relative / entry.name
                if relative == PurePosixPath(".") and beside(Path(entry.path)):
                    continue
                st = entry.stat(follow_symlinks=False)
                if stat.S_ISDIR(st.st_mode):
                    if name not in ways or not only(Path(entry.path), name):
                        return False
                elif not (stat.S_ISREG(st.st_mode) and noted.get(name) == _identity(st)):
                    return False
        return True

    try:
        return only(target, PurePosixPath("."))
    except FileNotFoundError:
        return not os.path.lexists(target)
    except OSError:
        return False


def _remove(target: Path, name: PurePosixPath, identity: Identity) -> None:
    """Unlink ``target/name`` if it has ``identity``, then the folders on its way that this leaves empty; each folder
    is opened without following a link, so a link put there meanwhile leads nowhere."""
    fds = [os.open(target, os.O_RDONLY | os.O_DIRECTORY)]
    try:
        for part in name.parts[:-1]:
            fds.append(os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=fds[-1]))
        with contextlib.suppress(OSError):
            if _identity(os.stat(name.name, dir_fd=fds[-1], follow_symlinks=False)) == identity:
                os.unlink(name.name, dir_fd=fds[-1])
        for part, fd in zip(reversed(name.parts[:-1]), reversed(fds[:-1])):
            os.rmdir(part, dir_fd=fd)  # only if empty: OSError ends it
    finally:
        for fd in fds:
            os.close(fd)
