"""Starting a thread or process the run depends on, where the OS may refuse it (its thread or process limit, memory).

``Thread.start`` raises RuntimeError then, ``Process.start`` OSError (EAGAIN from the fork or spawn): a traceback
that ended a run, after the record had replaced the old one. Each caller makes the refusal its own one-line error (a
bridge not connected, a policy lost at start-up, a record not started).
"""

from __future__ import annotations

import threading
from multiprocessing.process import BaseProcess


def start_thread(thread: threading.Thread) -> str | None:
    """Start ``thread``; None, or why the OS refused it."""
    return _start(thread, "thread", RuntimeError)


def start_process(process: BaseProcess) -> str | None:
    """Start ``process``; None, or why the OS refused it (not started: nothing to join or kill)."""
    return _start(process, "process", OSError)


def _start(worker: threading.Thread | BaseProcess, kind: str, refused: type[Exception]) -> str | None:
    """Start ``worker``; None, or why: the ``refused`` exception it raised, as one line."""
    try:
        worker.start()
    except refused as exc:
        return f"its {kind} {worker.name!r} could not start ({exc})"
    return None
