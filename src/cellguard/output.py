"""Writing an output file or folder: a failure is one error that names the path, never a traceback.

Every artefact (summary.json, baseline.json, report.html, exports) is written beside its target
under a temporary name, flushed to disk and then renamed over the target, so a full disk or a
crash leaves either the old file or the new one, never a 0-byte or half-written file.
"""

from __future__ import annotations

import contextlib
import os
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
        raise OutputError(f"{what} {path}: cannot create the folder ({_why(exc)})") from None
    return path


@contextlib.contextmanager
def atomic_file(path: Path, what: str) -> Iterator[BinaryIO]:
    """A binary file that becomes ``path`` only when the block ends without an error.

    The data goes to a temporary file in the same folder (same filesystem, so the rename is
    atomic), is fsynced, and then replaces ``path``; on any error the temporary file is removed,
    ``path`` is untouched and OutputError names it.
    """
    path = Path(path)
    if path.is_dir():  # the rename would fail only after all the data was written
        raise OutputError(f"{what} {path}: is a folder; name a file to write")
    make_folder(path.parent, what)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        raise OutputError(f"{what} {path}: cannot write ({_why(exc)}); any earlier file there is unchanged") from None
    except BaseException:
        _remove(tmp)
        raise


def write_output(path: Path, data: str | bytes, what: str) -> Path:
    """Write ``data`` to ``path`` (a ``what``, e.g. "report") atomically, creating its folder."""
    path = Path(path)
    with atomic_file(path, what) as f:
        f.write(data if isinstance(data, bytes) else data.encode("utf-8"))
    return path


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()


def _why(exc: OSError) -> str:
    return exc.strerror or exc.__class__.__name__
