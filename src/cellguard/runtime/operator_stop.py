"""The operator's Ctrl-C (SIGINT), a service manager's SIGTERM, or a closed terminal's SIGHUP, as a stop input
rather than an exception.

A KeyboardInterrupt raised mid-tick would leave the robot with no setpoint in the middle of a
motion (and LeRobot's ``disconnect`` then drops the torque), and the record would end with no
word of why. Instead, while the cycles run, the first signal is a category 2 stop request like a
stop button: the guard brings the robot to a standstill, the run ends, the record names the stop
(``operator_stop``) and the retreat to home follows. A second signal aborts the retreat (the robot
holds where it is); a third raises KeyboardInterrupt as Python would, but never mid-brake: within ``brake_s`` of
the signal before it (the longest a stop's brake takes) it is said on stderr and raised once the loop finds the
command at rest (``at_rest``). A held Ctrl-C repeats about 30 times a second: its third signal ended the setpoints
of a brake at 2.1 rad/s, a dead stop for a drive holding its last setpoint. Past ``brake_s`` a signal raises at
once, so a hung program still ends.

Handlers are installed only on the main thread (Python delivers signals there) and restored on exit. A signal
ignored when the block starts stays ignored: under ``nohup`` (SIGHUP ignored) a closed terminal stopped the run the
user had asked to outlive it; a shell or a daemon keeps an inherited SIG_IGN too.
``with`` nests: the handlers stay until the outermost block ends, which ``run_scenario`` keeps open while
the record closes and the summary is written (a second quick Ctrl-C there met Python's own handler:
exit 130 and no summary.json; a SIGTERM killed the process without a word).
"""

from __future__ import annotations

import signal
import sys
import threading
import time

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # SIGHUP: the terminal or ssh session closed
INSIST = 3  # the signal that raises KeyboardInterrupt after all
REASON = "operator stop"


def by_operator(stopped: str | None) -> bool:
    """Whether a run's ``stopped`` says the operator stopped it."""
    return bool(stopped) and stopped.startswith(REASON)


class OperatorStop:
    """Counts the stop signals received while installed (``with``); ``signal`` names the first. ``brake_s``: how
    long a brake started by a signal may take [s, wall time] (0: a third signal raises at once)."""

    def __init__(self, brake_s: float = 0.0):
        self.count = 0
        self.signal: str | None = None
        self.brake_s = brake_s
        self.waiting = 0  # the signals that insisted during a brake, raised at ``at_rest``
        self._braking_until = 0.0  # [s] time.monotonic(): a brake may still run until then
        self._moving = True  # motion may follow (cycles, transitions): a signal starts a brake; False: ``motion_over``
        self._previous: dict[int, object] = {}
        self._depth = 0  # nested ``with`` blocks: the outermost installs and restores

    def __enter__(self) -> OperatorStop:
        self._depth += 1
        if self._depth == 1 and threading.current_thread() is threading.main_thread():
            for signum in SIGNALS:
                if signal.getsignal(signum) is not signal.SIG_IGN:
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

    def at_rest(self) -> None:
        """The command is at rest: no brake runs; a signal that insisted during it raises KeyboardInterrupt now."""
        self._braking_until = 0.0
        if self.waiting:
            self.waiting = 0
            raise KeyboardInterrupt

    def motion_over(self) -> None:
        """No motion follows (the run closes its record): a signal starts no brake, so the third raises at once. It
        opened the brake's window still, and a third signal then waited for a rest that never came: swallowed."""
        self._moving = False
        self._braking_until = 0.0

    def _received(self, signum: int, frame) -> None:
        self.count += 1
        self.signal = self.signal or signal.Signals(signum).name
        now = time.monotonic()
        if self.count < INSIST:  # a stop, or the retreat's abort: a brake starts
            self._braking_until = now + self.brake_s if self._moving else 0.0
        elif now < self._braking_until:
            self.waiting += 1
            if self.waiting == 1:
                sys.stderr.write(f"{signal.Signals(signum).name} again during the brake: KeyboardInterrupt once the "
                                 f"robot is at rest (a signal {self.brake_s:.1f} s after the one before raises it at "
                                 "once)\n")
        else:
            raise KeyboardInterrupt
