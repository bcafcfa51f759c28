"""An output made in a staging folder and moved into its target in several moves, undone as a whole if cut short.

``to-lerobot`` and ``recover`` write into a staging folder of their own, locked while their process lives
(``folder_lock``), and then move its files into the target one part at a time (the target stays the same folder: it
may be a shell's current one). Killed (SIGKILL) between two moves, a run left a target holding some of the files: the
rerun refused it as not empty, and the user had to pick files out by hand. So before its first move a run notes in
its staging folder each file it holds with its identity (device, inode: a rename and a hard link keep it). Whoever
clears a killed run's staging folder takes out of the target exactly the noted files still there under the same
identity, and the folders that leaves empty: never a file someone else put there, nor a live run's (its staging
folder is locked). A target that got every file is a finished output and is kept as one.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterable
from pathlib import Path, PurePosixPath

from cellguard.errors import RecordError
from cellguard.record import folder_lock

NOTED = ".moved-files.json"  # in the staging folder: [[relative path, device, inode], ...], written before any move


def note_files(staging: Path) -> list[Path]:
    """Every file under ``staging`` (relative paths, sorted), noted with its identity in its ``NOTED`` file (flushed
    to disk before the first move: the moves may reach the disk before it otherwise)."""
    files = sorted(p.relative_to(staging) for p in staging.rglob("*") if p.is_file() and not p.is_symlink())
    noted = [[f.as_posix(), st.st_dev, st.st_ino] for f in files for st in [os.lstat(staging / f)]]
    with open(staging / NOTED, "w") as out:
        json.dump(noted, out)
        out.flush()
        os.fsync(out.fileno())
    return files


def take_back(staging: Path, target: Path) -> None:
    """Remove from ``target`` the files noted in ``staging`` that are there under the same identity, and the folders
    on their way up to ``target`` that this leaves empty. Nothing noted (the run stopped before its moves): nothing."""
    _remove(_placed(staging, target)[0], target)


def _remove(files: list[Path], target: Path) -> None:
    for path in files:
        with contextlib.suppress(OSError):
            path.unlink()
        for folder in path.parents:
            if folder == target:
                break
            try:
                folder.rmdir()  # only if empty
            except OSError:
                break


def clear_killed(leftovers: Iterable[Path], target: Path, busy: str) -> None:
    """Remove the staging folders of runs into ``target`` killed before their clean-up (no process holds their lock),
    with what they had moved into ``target`` unless they had moved it all; RecordError ``busy`` (naming the folder) if
    one is still held by a live run, whose folder and files are left as they are."""
    for old in leftovers:
        try:
            lock = folder_lock.hold(old, "-o")
        except RecordError:
            raise RecordError(f"{busy} ({old.name}); wait for it to end or give another folder") from None
        try:
            placed, noted = _placed(old, target)
            if len(placed) < noted:  # cut short: the rerun makes it again
                _remove(placed, target)
            shutil.rmtree(old, ignore_errors=True)
        finally:
            folder_lock.release(lock)


def _placed(staging: Path, target: Path) -> tuple[list[Path], int]:
    """The noted files of ``staging`` that are in ``target`` under the same identity, and how many were noted (0 if
    the note cannot be read: it was not whole before the first move). A noted path out of ``target`` is never one."""
    try:
        noted = json.loads((staging / NOTED).read_text())
        entries = [(PurePosixPath(name), int(dev), int(ino)) for name, dev, ino in noted]
    except (OSError, ValueError, TypeError):
        return [], 0
    placed = []
    for name, dev, ino in entries:
        if not name.parts or name.is_absolute() or ".." in name.parts:
            continue
        path = target / name
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if (st.st_dev, st.st_ino) == (dev, ino):
            placed.append(path)
    return placed, len(entries)
