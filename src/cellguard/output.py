"""Writing an output file or folder: a failure is one error that names the path, never a traceback.

Every artefact (summary.json, baseline.json, report.html, exports) is written beside its target
under a temporary name, flushed to disk and then renamed over the target, so a full disk or a
crash leaves either the old file or the new one, never a 0-byte or half-written file.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from cellguard.errors import OutputError

NAME_MAX = 255  # the longest file name, in bytes, on ext4, XFS, btrfs and APFS
PID_MAX = 4194304  # the highest pid Linux gives (2**22), for the longest temporary name
TOKEN_BYTES = 4  # random bytes (hex) after the pid: two writers of one pid (two containers' first process) differ
TEMPORARY_SUFFIX = ".tmp"
TEMPORARY_TRIES = 100  # a temporary file taken from under a write is made again at most this often
UNLOCKABLE = (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL)  # flock is not offered there
# what an output never replaces, by the bytes it starts with (a link followed to one destroyed another run's record)
NEVER_REPLACED = {b"\x89MCAP0\r\n": "a record (MCAP)", b"SQLite format 3\x00": "an SQLite database (a store)"}


def make_folder(path: Path, what: str) -> Path:
    """Create the folder ``path`` (a ``what``, e.g. "--out") and its parents."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        for part in (path, *path.parents):
            if part.is_symlink() and not part.exists():
                raise OutputError(f"{what} {path}: {part} is a link to {os.readlink(part)}, which does not exist; "
                                  f"create its target or name another folder") from None
        raise OutputError(f"{what} {path}: cannot create the folder ({_why(exc)})") from None
    return path


def refuse_filled_folder(path: Path, what: str, left: str = "") -> None:
    """OutputError if ``path`` is a folder that holds anything: a dataset or a recovered record goes only into a new
    or empty folder, so that nothing of another run's (a record's index parts, a dataset's files) is mixed in,
    replaced or removed. ``left``: what a stopped run left there, said after it (``staged.clear_killed``)."""
    try:
        filled = path.is_dir() and any(path.iterdir())
    except OSError as exc:
        raise OutputError(f"{what} {path}: cannot be read ({_why(exc)})") from None
    if filled:
        hint = f" or empty it: {left}" if left else ""
        raise OutputError(f"{what} {path}: exists and is not empty; give a new folder{hint}")


@contextlib.contextmanager
def atomic_file(path: Path, what: str, replace: bool = True, mode: int = 0o666) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` only when the block ends without an error.

    The data goes to a temporary file in the same folder (same filesystem, so the rename is
    atomic), is fsynced, and then replaces ``path``; on any error the temporary file is removed,
    ``path`` is untouched and OutputError names it. The temporary file is locked while it is written, so
    the one of a write killed outright (no clean-up ran) is told from a live one's and removed by the next
    write of ``path``. With ``replace=False`` a file that appeared at
    ``path`` while the data was made is kept and OutputError says so (a check at the start of a
    long job does not hold at its end). A link is followed: its final target is what is checked,
    written beside and replaced, so a link is never turned into a file (``-o`` naming a link to
    /proc/self/fd/1 with stdout redirected to a file replaced the link and left the file empty).
    A folder, device, FIFO or socket there is refused before anything is written, and the target is
    looked up again just before the rename. ``mode`` is the new file's permissions before the umask
    (0o640: a site's own data, not for every local user).
    """
    path = Path(path)
    _final_target(path, what)  # refused before any folder is made
    make_folder(path.parent, what)
    target = _final_target(path, what)
    _clear_stale_temporaries(target)
    try:
        with _locked_temporary(target, mode) as (tmp, f):  # locked until closed: no write takes it for a killed one's
            try:
                yield f
                f.flush()
                os.fsync(f.fileno())
                if replace:
                    if _final_target(path, what) != target:  # a link put or moved there while the data was written
                        raise FileExistsError(path)
                    os.replace(tmp, target)  # a FIFO or folder made there meanwhile was refused just above
                else:
                    _rename_new(tmp, target)
            except BaseException:
                _remove_own(tmp, f.fileno())  # while still open and locked
                raise
    except FileExistsError:
        raise OutputError(f"{what} {path}: something was put there while it was being made; it is kept "
                          "(nothing written)") from None
    except OSError as exc:
        raise OutputError(f"{what} {path}: cannot write ({_why(exc)}); any earlier file there is unchanged") from None


def _final_target(path: Path, what: str) -> Path:
    """The file that writing ``path`` would replace or make: ``path`` with every link followed, absolute.

    OutputError unless that is a regular file or nothing: a rename replaces a device, FIFO or socket node
    itself and fails on a folder only after all the data was written. A link to an open file that no name
    reaches (/proc/self/fd/N of a pipe, a terminal or a deleted file) is refused, as is a dangling link whose
    target's folder does not exist; a dangling link into an existing folder makes its target there.
    """
    try:
        try:
            mode = os.stat(path).st_mode  # follows links, /proc/self/fd/N included
        except (FileNotFoundError, NotADirectoryError):
            return _new_target(path, what)
        if stat.S_ISDIR(mode):
            raise OutputError(f"{what} {path}: is a folder; name a file to write")
        kind = not_regular(path)
        target = Path(os.path.realpath(path))
        # only a link can reach an unnamed file: a plain name replaced by another write of it between samefile's two
        # looks read as one (1 in 170 writes of one file by 8 processes at once failed)
        unnamed = kind is None and path.is_symlink() and not (target.exists() and os.path.samefile(path, target))
        points_to = os.readlink(path) if unnamed else None
    except OSError as exc:  # a name too long, a link loop, no access: one line, not a traceback
        raise OutputError(f"{what} {path}: cannot write ({_why(exc)}); nothing written") from None
    if kind is not None:
        raise OutputError(f"{what} {path}: is {kind}, not a regular file; cellguard replaces only regular files: "
                          f"choose another path (nothing written)")
    if unnamed:
        raise OutputError(f"{what} {path}: is a link to {points_to}, which no file name reaches; "
                          f"choose another path (nothing written)")
    kept = never_replaced(target)
    if kept is not None:
        via = "" if target == Path(os.path.abspath(path)) else f" (through a link to {target})"
        raise OutputError(f"{what} {path}: is {kept}{via}; cellguard never overwrites a record or a store: choose "
                          f"another path (nothing written)")
    return target


def never_replaced(target: Path) -> str | None:
    """What ``target`` is if it is a file an output never replaces (a record, a store), else None."""
    try:
        with open(target, "rb") as f:
            head = f.read(max(map(len, NEVER_REPLACED)))
    except OSError:  # unreadable: the write that follows says why
        return None
    return next((what for magic, what in NEVER_REPLACED.items() if head.startswith(magic)), None)


def _new_target(path: Path, what: str) -> Path:
    """Where a missing ``path`` is made: a dangling link's target, if its folder exists (the link stays)."""
    target = Path(os.path.realpath(path))
    if path.is_symlink() and not target.parent.is_dir():
        raise OutputError(f"{what} {path}: is a link to {os.readlink(path)}, whose folder does not exist; "
                          f"create it or name another file (nothing written)")
    return target


def _temporary_name(name: str) -> str:
    """A hidden temporary name beside ``name`` (``.NAME.PID.TOKEN.tmp``, TOKEN random) that stays within the 255 bytes
    a file name may have."""
    return f"{_temporary_prefix(name)}{os.getpid()}.{os.urandom(TOKEN_BYTES).hex()}{TEMPORARY_SUFFIX}"


def _temporary_prefix(name: str, longest: str = f"{PID_MAX}.{'0' * 2 * TOKEN_BYTES}") -> str:
    """What every temporary name beside ``name`` starts with, whatever its pid and token: the same hashed or not.
    ``longest``: the longest part after it (``str(PID_MAX)``: the names before the token, ``.NAME.PID.tmp``)."""
    if len(os.fsencode(f".{name}.{longest}{TEMPORARY_SUFFIX}")) > NAME_MAX:
        name = hashlib.sha256(os.fsencode(name)).hexdigest()[:32]
    return f".{name}."


@contextlib.contextmanager
def folder_locked(folder: Path, error: Callable[[str, OSError], Exception], unguarded: bool = False) -> Iterator[None]:
    """An exclusive ``flock`` on ``folder`` while the block runs (a second holder waits): a lock on the folder, not a
    lock file, leaves nothing behind. ``error(doing, exc)``: what to raise when the folder cannot be opened
    (``"open"``) or locked (``"lock"``); ``unguarded``: on a filesystem that offers no locks the block runs anyway."""
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise error("open", exc) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as exc:
            if not (unguarded and exc.errno in UNLOCKABLE):
                raise error("lock", exc) from None
        yield
    finally:
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def _locked_temporary(target: Path, mode: int) -> Iterator[tuple[Path, BinaryIO]]:
    """A new temporary file beside ``target`` (its path and the file), open for writing and ``flock``ed until the
    block ends: a lock not held marks the temporary file of a killed write (``_clear_stale_temporaries``). Without
    locks there, it is written unlocked. Made new (``O_EXCL``) under a name no other write has: two writers of one
    pid (in two pid namespaces) shared ``.NAME.PID.tmp`` and, unlocked, published a mix of both; nothing already
    there is opened (a FIFO there hung the write), it is a name taken, and another is drawn."""
    for _ in range(TEMPORARY_TRIES):
        tmp = target.with_name(_temporary_name(target.name))
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
        except FileExistsError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # a clearing write holds it a moment
            if _same_file(os.fstat(fd), os.lstat(tmp)):
                break
        except FileNotFoundError:  # a clearing write took it for a killed one's before it was locked: made again
            pass
        except OSError as exc:
            if exc.errno not in UNLOCKABLE:
                os.close(fd)
                raise
            break
        os.close(fd)
    else:  # taken from under it again and again: no file of its own to write
        raise FileExistsError(target)
    with os.fdopen(fd, "wb") as f:
        yield tmp, f


def _clear_stale_temporaries(target: Path) -> None:
    """Remove the temporary files beside ``target`` of writes killed before their clean-up (SIGKILL: each stayed for
    good, as large as its output): those whose lock is free. One a live write holds, or one that cannot be locked
    (a filesystem without locks), is kept."""
    prefixes = {_temporary_prefix(target.name), _temporary_prefix(target.name, str(PID_MAX))}  # and before the token
    mine = re.compile(f"(?:{'|'.join(map(re.escape, prefixes))})" + r"\d+(?:\.[0-9a-f]+)?"
                      + re.escape(TEMPORARY_SUFFIX))
    try:
        names = [name for name in os.listdir(target.parent) if mine.fullmatch(name)]
    except OSError:  # the write itself says why the folder cannot be used
        return
    for name in names:
        _remove_if_stale(target.parent / name)


def _remove_if_stale(tmp: Path) -> None:
    """Remove the regular file ``tmp`` if no process holds its lock, still under this name once locked here."""
    try:
        if not stat.S_ISREG(os.lstat(tmp).st_mode):  # a folder, link or device of that name is not even opened
            return
        fd = os.open(tmp, os.O_RDWR | os.O_NOFOLLOW | os.O_NONBLOCK)  # for writing: NFS locks only such a file
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # OSError: a live write holds it, or no locks here
        if _same_file(os.fstat(fd), os.lstat(tmp)):
            os.unlink(tmp)
    except OSError:
        pass
    finally:
        os.close(fd)


def _same_file(a: os.stat_result, b: os.stat_result) -> bool:
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def write_output(path: Path, data: str | bytes, what: str, replace: bool = True) -> Path:
    """Write ``data`` to ``path`` (a ``what``, e.g. "report") atomically, creating its folder."""
    path = Path(path)
    with atomic_file(path, what, replace) as f:
        f.write(data if isinstance(data, bytes) else data.encode("utf-8"))
    return path


def keep_output(path: Path, data: str | bytes, what: str) -> Path:
    """``write_output`` unless ``path`` is a regular file holding exactly ``data`` already: a file made again from its
    source (a record's baseline.json and fixes.json) is left as it is, so a record on read-only storage (an archive)
    is diagnosed and reported as often as wanted; it failed on a write that would have changed nothing."""
    path = Path(path)
    data = data if isinstance(data, bytes) else data.encode("utf-8")
    try:
        same = path.is_file() and path.stat().st_size == len(data) and path.read_bytes() == data
    except OSError:  # cannot be read or looked at: the write says why
        same = False
    return path if same else write_output(path, data, what)


def not_regular(path: Path) -> str | None:
    """What ``path`` is, after following links, if it exists and is neither a regular file nor a folder ("a FIFO",
    ...); None otherwise. A rename replaces such a node itself: a device file (as root, /dev/null) becomes a
    regular file. OSError if ``path`` cannot be looked at (other than not being there)."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):  # a dangling link is replaced, as a missing file is made
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    return special_kind(mode)


def special_kind(mode: int) -> str:
    """What a file of ``mode`` that is neither a regular file nor a folder is, in words ("a FIFO", ...)."""
    kinds = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
             (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(mode)), "a special file")


def _rename_new(tmp: Path, path: Path) -> None:
    """Rename ``tmp`` to ``path`` unless something is there (FileExistsError): a hard link is atomic; where the
    filesystem has none, a check just before the rename."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK):
            raise
        if path.exists() or path.is_symlink():
            raise FileExistsError(path) from None
        os.replace(tmp, path)
        return
    _remove(tmp)


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()


def _remove_own(tmp: Path, fd: int) -> None:
    """Remove ``tmp`` only while it is still the file open on ``fd``: after the rename (a signal may stop the write
    right after it) the name is free, and whatever is there now belongs to another write."""
    with contextlib.suppress(OSError):
        if _same_file(os.fstat(fd), os.lstat(tmp)):
            os.unlink(tmp)


def _why(exc: OSError) -> str:
    return exc.strerror or exc.__class__.__name__
