"""SIGTERM and SIGHUP as an exception, so that a command's clean-up runs (its ``finally`` blocks)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

ENDING = (signal.SIGTERM, signal.SIGHUP)  # what `timeout`, `kill`, a service's stop and a closed terminal send


@contextlib.contextmanager
def ended_by_signals() -> Iterator[None]:
    """While a command (or a benchmark) runs, SIGTERM or SIGHUP end it as Ctrl-C does, by an exception (SystemExit, 128 + the signal:
    143 for SIGTERM), so that its clean-up runs: killed outright, an export left its hidden temporary file or
    staging folder beside the target for good. A run's operator stop (``runtime.operator_stop``) takes both over
    while it runs; either signal in a forked child ends the process at once as before (no exception mid-tick).
    Installed only on the main thread (Python delivers signals there), restored after. A signal ignored when the
    command starts stays ignored (``nohup``'s SIGHUP: a closed terminal ended a run the user had asked to outlive
    it), as a shell or a daemon keeps an inherited SIG_IGN."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pid = os.getpid()

    def end(signum: int, frame) -> None:
        if os.getpid() != pid:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        raise SystemExit(128 + signum)

    previous = {signum: signal.signal(signum, end) for signum in ENDING
                if signal.getsignal(signum) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
