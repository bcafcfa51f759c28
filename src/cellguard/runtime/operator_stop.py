"""The operator's Ctrl-C (SIGINT), a service manager's SIGTERM, or a closed terminal's SIGHUP, as a stop input
rather than an exception.

A KeyboardInterrupt raised mid-tick would leave the robot with no setpoint in the middle of a
motion (and LeRobot's ``disconnect`` then drops the torque), and the record would end with no
word of why. Instead, while the cycles run, the first signal is a category 2 stop request like a
stop button: the guard brings the robot to a standstill, the run ends, the record names the stop
(``operator_stop``) and the retreat to home follows. A second signal aborts the retreat (the robot
holds where it is); a third raises KeyboardInterrupt as Python would.

Handlers are installed only on the main thread (Python delivers signals there) and restored on exit.
``with`` nests: the handlers stay until the outermost block ends, which ``run_scenario`` keeps open while
the record closes and the summary is written (a second quick Ctrl-C there met Python's own handler:
exit 130 and no summary.json; a SIGTERM killed the process without a word).
"""

from __future__ import annotations

import signal
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # SIGHUP: the terminal or ssh session closed
INSIST = 3  # the signal that raises KeyboardInterrupt after all
REASON = "operator stop"


def by_operator(stopped: str | None) -> bool:
    """Whether a run's ``stopped`` says the operator stopped it."""
    return bool(stopped) and stopped.startswith(REASON)


class OperatorStop:
    """Counts the stop signals received while installed (``with``); ``signal`` names the first."""

    def __init__(self):
        self.count = 0
        self.signal: str | None = None
        self._previous: dict[int, object] = {}
        self._depth = 0  # nested ``with`` blocks: the outermost installs and restores

    def __enter__(self) -> OperatorStop:
        self._depth += 1
        if self._depth == 1 and threading.current_thread() is threading.main_thread():
            for signum in SIGNALS:
                self._previous[signum] = signal.signal(signum, self._received)
        return self

    def __exit__(self, *exc) -> None:
        self._depth -= 1
        if self._depth:
            return
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    @property
    def reason(self) -> str:
        """Why the run stopped, as the summary says it (``stopped``)."""
        return f"{REASON} ({self.signal})"

    def _received(self, signum: int, frame) -> None:
        self.count += 1
        self.signal = self.signal or signal.Signals(signum).name
        if self.count >= INSIST:
            raise KeyboardInterrupt
