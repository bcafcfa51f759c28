"""This host's clock and a record's wall times as UTC dates, made here only: a site's dates are compared with
the fleet store's UTC date (``store.SERVER_DATE``, retention) and name the lake's day partitions, so a local
date would move them by the host's time zone."""

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
