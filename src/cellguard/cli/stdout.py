"""A stdout that a command cannot write to ends the command in one line, never a traceback.

Every command writes its output through ``sys.stdout`` (rich's consoles included). ``guard()``, run before
any command, puts a thin wrapper there whose writes and flushes turn an OSError into the command's end: a
reader that stopped early (``| head``) ends it quietly with 141, as ``cat`` does; stdout closed (``>&-``) or
full (``> /dev/full``) is one line on stderr and exit 2, or 1 once the command has written what it makes
(``written()``, called by every command that writes, moves or deletes something, as soon as that is stored: a
record, a page, a release log entry, which the line then names as kept; 2 says nothing was done). Before, each
was a traceback, or exit 1 (rich and click end a closed pipe so), which reads as "the record is damaged".
"""

from __future__ import annotations

import os
import sys

from cellguard.cli.text import printable

EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE: what `cat` or `git log` return when `| head` stops reading
_done = {"written": None}  # what the command has written when its stdout fails, if anything


class _Guarded:
    """``stream`` (stdout) whose failing write or flush ends the command (``_end``)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            _end(exc)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            _end(exc)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


class _Closed:
    """File descriptor 1 closed (Python's stdout is None): the first write ends the command."""

    encoding = "utf-8"

    def write(self, text: str) -> int:
        _end(OSError("stdout is closed"))

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


def _end(exc: OSError) -> None:
    try:  # what is still buffered goes nowhere at exit instead of failing again
        os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    except OSError:
        pass
    if isinstance(exc, BrokenPipeError):  # the reader took what it wanted
        raise SystemExit(EXIT_BROKEN_PIPE)
    kept = f"; {printable(_done['written'])} is written and kept" if _done["written"] else ""
    sys.stderr.write(f"error: stdout: cannot write the output ({exc.strerror or exc}){kept}\n")
    raise SystemExit(1 if _done["written"] else 2)


def written(what: object) -> None:
    """The command has written ``what`` (a run folder, a report): a stdout that fails from now on exits 1."""
    _done["written"] = what


def guard() -> None:
    """Wrap ``sys.stdout`` (once) so that a failing write ends the command as the module says."""
    _done["written"] = None
    if not isinstance(sys.stdout, (_Guarded, _Closed)):
        _hold_closed_descriptors()
        sys.stdout = _Closed() if sys.stdout is None else _Guarded(sys.stdout)


def _hold_closed_descriptors() -> None:
    """Put /dev/null on a closed descriptor 0, 1 or 2: else the next file the command opens takes its number, a
    child process inherits that file as its stdin, stdout or stderr, and ``_end`` put /dev/null over it."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)  # the lowest free number: this one, or a lower closed one
            if null != fd:
                os.dup2(null, fd)
                os.close(null)


def require_open() -> None:
    """End the command now if stdout is closed (before a query starts that would write there)."""
    guard()
    if isinstance(sys.stdout, _Closed):
        sys.stdout.write("")
