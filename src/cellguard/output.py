"""Writing an output file or folder: a failure is one error that names the path, never a traceback."""

from __future__ import annotations

from pathlib import Path

from cellguard.errors import OutputError


def make_folder(path: Path, what: str) -> Path:
    """Create the folder ``path`` (a ``what``, e.g. "--out") and its parents."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{what} {path}: cannot create the folder ({exc.strerror or exc.__class__.__name__})") from None
    return path


def write_output(path: Path, data: str | bytes, what: str) -> Path:
    """Write ``data`` to ``path`` (a ``what``, e.g. "report"), creating its folder."""
    path = Path(path)
    make_folder(path.parent, what)
    try:
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data, encoding="utf-8")
    except OSError as exc:
        raise OutputError(f"{what} {path}: cannot write ({exc.strerror or exc.__class__.__name__})") from None
    return path
