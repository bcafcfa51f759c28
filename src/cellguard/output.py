"""Writing an output file or folder: a failure is one error that names the path, never a traceback.

Every artefact (summary.json, baseline.json, report.html, exports) is written beside its target
under a temporary name, flushed to disk and then renamed over the target, so a full disk or a
crash leaves either the old file or the new one, never a 0-byte or half-written file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from cellguard.errors import OutputError


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


@contextlib.contextmanager
def atomic_file(path: Path, what: str, replace: bool = True) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` only when the block ends without an error.

    The data goes to a temporary file in the same folder (same filesystem, so the rename is
    atomic), is fsynced, and then replaces ``path``; on any error the temporary file is removed,
    ``path`` is untouched and OutputError names it. With ``replace=False`` a file that appeared at
    ``path`` while the data was made is kept and OutputError says so (a check at the start of a
    long job does not hold at its end). A folder, device, FIFO or socket at ``path`` is refused before anything is
    written, and checked again just before the rename.
    """
    path = Path(path)
    _check_target(path, what)
    make_folder(path.parent, what)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        if replace:
            _check_target(path, what)  # one made while the data was written would be replaced too
            os.replace(tmp, path)
        else:
            _rename_new(tmp, path)
    except FileExistsError:
        _remove(tmp)
        raise OutputError(f"{what} {path}: something was put there while it was being made; it is kept "
                          "(nothing written)") from None
    except OSError as exc:
        _remove(tmp)
        raise OutputError(f"{what} {path}: cannot write ({_why(exc)}); any earlier file there is unchanged") from None
    except BaseException:
        _remove(tmp)
        raise


def write_output(path: Path, data: str | bytes, what: str, replace: bool = True) -> Path:
    """Write ``data`` to ``path`` (a ``what``, e.g. "report") atomically, creating its folder."""
    path = Path(path)
    with atomic_file(path, what, replace) as f:
        f.write(data if isinstance(data, bytes) else data.encode("utf-8"))
    return path


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
    kinds = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
             (stat.S_ISSOCK, "a socket"))
    return next((name for test, name in kinds if test(mode)), "a special file")


def _check_target(path: Path, what: str) -> None:
    """OutputError unless ``path`` is missing or a regular file: the rename would replace a device, FIFO or socket,
    and fail on a folder only after all the data was written."""
    try:
        if path.is_dir():
            raise OutputError(f"{what} {path}: is a folder; name a file to write")
        kind = not_regular(path)
    except OSError as exc:  # a name too long, a link loop, no access: one line, not a traceback
        raise OutputError(f"{what} {path}: cannot write ({_why(exc)}); nothing written") from None
    if kind is not None:
        raise OutputError(f"{what} {path}: is {kind}, not a regular file; cellguard replaces only regular files: "
                          f"choose another path (nothing written)")


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


def _why(exc: OSError) -> str:
    return exc.strerror or exc.__class__.__name__
