"""A slip the acceptance baseline holds, gone in the watched cycles: the tool back at its place on the flange.

A baseline taken while the tool had slipped (another record's acceptance, or the record's own) holds the slipped
part-to-tool offset at grasp. Once the tool is back in place the offset reads zero, its clean level
(``intermittent.AT_ZERO``), which the drift monitor read as a step off the baseline and the cause rules as a new
slip ("offset changed -1.4 mm"). Where the baseline's offset sits ``OUTLIER`` scales or more off zero and the
watched cycles read nearer zero than that level from some cycle to the last (``MIN_HITS`` or more, their median
within ``BETWEEN`` scales of zero on every axis), the slip is gone from that cycle: the offset is read from zero
there and the tool point at grasp from where the refitted tool puts it (a new slip from the clean level still
alarms), and the diagnosis says the baseline held it instead of naming a fault.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.diagnose.baseline import Baseline, feature_matrix
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.intermittent import AT_ZERO, BETWEEN, MIN_HITS, OUTLIER, nearer_level

TOOL_POINT = "grasp_tcp_"  # the tool point at grasp: the part less its offset, so the offset's change moves it back


@dataclass(frozen=True)
class SlipGone:
    """The slip the baseline holds, gone from ``cycle`` on: per offset feature, the baseline's level and the median
    reading from ``cycle`` on [mm]."""

    cycle: int
    signals: tuple[str, ...]
    held: tuple[float, ...]
    back: tuple[float, ...]
    slipped: tuple[int, int] | None = None  # the first and last watched cycle at the slipped level, if any

    def words(self) -> str:
        held = ", ".join(f"{v:+.1f} mm in {s.removeprefix(AT_ZERO)[0]}" for s, v in zip(self.signals, self.held))
        back = ", ".join(f"{v:+.1f} mm in {s.removeprefix(AT_ZERO)[0]}" for s, v in zip(self.signals, self.back))
        before = f" (cycles {self.slipped[0]} to {self.slipped[1]} read the slipped level)" if self.slipped else ""
        return (f"the acceptance baseline holds a slipped tool (part-to-tool offset at grasp {held}, where a tool "
                f"that holds its place reads 0); from cycle {self.cycle} on it reads {back}{before}: the slip is "
                "gone, not a new one; the offset is watched from 0 there. Take the baseline from a record whose "
                "tool held its place (--acceptance DIR)")

    def to_dict(self) -> dict:
        return {"cycle": self.cycle, "signals": list(self.signals), "baseline_mm": [round(v, 3) for v in self.held],
                "since_mm": [round(v, 3) for v in self.back], "slipped_cycles": self.slipped and list(self.slipped),
                "why": self.words()}


def slip_gone(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray) -> SlipGone | None:
    """The slip ``baseline`` holds, gone in ``cycles`` (residuals ``z``, Shape (cycles, features)); None where the
    baseline holds none (no axis of the offset ``OUTLIER`` scales off zero), or the offset is not back at zero on
    every axis on the last cycles."""
    cols = [j for j, n in enumerate(baseline.names) if n.startswith(AT_ZERO)]
    if not cols or not len(cycles):
        return None
    centre, scale = (m[:, cols] for m in baseline.centre_and_scale(cycles))
    with np.errstate(invalid="ignore"):
        if not np.any(np.all(np.abs(centre) >= OUTLIER * scale, axis=0)):
            return None
    x = feature_matrix(cycles, [baseline.names[j] for j in cols]) / scale
    seen = ~np.isnan(z[:, cols]).any(axis=1) & ~np.isnan(x).any(axis=1)
    off = np.flatnonzero(seen & nearer_level(x, centre / scale))
    tail = np.flatnonzero(seen & (np.arange(len(cycles)) > (off[-1] if len(off) else -1)))
    if len(tail) < MIN_HITS or np.any(np.abs(np.median(x[tail], axis=0)) > BETWEEN):
        return None
    return SlipGone(cycles[tail[0]].index, tuple(baseline.names[j] for j in cols),
                    tuple(float(v) for v in np.median(centre, axis=0)),
                    tuple(float(v) for v in np.median(x[tail] * scale[tail], axis=0)),
                    (cycles[off[0]].index, cycles[off[-1]].index) if len(off) else None)


def read_from_zero(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, gone: SlipGone | None) -> np.ndarray:
    """``z`` with the cycles from ``gone.cycle`` on read from where a tool in its place puts them, not from the
    baseline's slipped tool: the offset from zero, the tool point (``TOOL_POINT``, the part less the offset) from
    the baseline's plus the offset it held (``z`` itself where nothing is gone)."""
    if gone is None:
        return z
    z = z.copy()
    rows = np.array([c.index >= gone.cycle for c in cycles])
    centre, scale = baseline.centre_and_scale([c for c, r in zip(cycles, rows) if r])
    for name in gone.signals:
        held = centre[:, baseline.names.index(name)]
        for other, sign in ((name, 1.0), (name.replace(AT_ZERO, TOOL_POINT), -1.0)):
            if other in baseline.names:
                j = baseline.names.index(other)
                z[rows, j] += sign * held / scale[:, j]
    return z
