"""Starting a thread the run depends on, where the OS may refuse it (its thread limit, memory).

``Thread.start`` raises RuntimeError then: a traceback that ended a run, after the record had replaced the old one.
Each caller makes the refusal its own one-line error (a bridge not connected, a policy lost at start-up, a record
not started).
"""

from __future__ import annotations

import threading


def start_thread(thread: threading.Thread) -> str | None:
    """Start ``thread``; None, or why the OS refused it."""
    try:
        thread.start()
    except RuntimeError as exc:
        return f"its thread {thread.name!r} could not start ({exc})"
    return None
