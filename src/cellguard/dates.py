"""This host's clock and wall times as UTC dates, made here only: a site's dates are compared with the fleet
store's UTC date, name the lake's day partitions and stamp calibrations, so a local date would move them by the
host's time zone (west of UTC a local ``today`` is the day before). A leaf: it imports nothing of cellguard's."""

from __future__ import annotations

import datetime as dt


def utc_now() -> dt.datetime:
    """This host's clock, in UTC."""
    return dt.datetime.now(dt.timezone.utc)


def utc_today() -> dt.date:
    """This host's UTC date."""
    return utc_now().date()


def utc_day(epoch_ns: int) -> dt.date:
    """The UTC date of a wall time in nanoseconds since the epoch (a record's start)."""
    return dt.datetime.fromtimestamp(epoch_ns * 1e-9, dt.timezone.utc).date()
