"""A slip the acceptance baseline holds, gone in the watched cycles: the tool back at its place on the flange.

A baseline taken while the tool had slipped (another record's acceptance, or the record's own) holds the slipped
part-to-tool offset at grasp. Once the tool is back in place the offset reads zero, its clean level
(``intermittent.AT_ZERO``), which the drift monitor read as a step off the baseline and the cause rules as a new
slip ("offset changed -1.4 mm"). Where the baseline's offset sits ``OUTLIER`` scales or more off zero and the
watched cycles read nearer zero than that level from some cycle to the last (``MIN_HITS`` or more, their median
within ``BETWEEN`` scales of zero on every slipped axis), after one unbroken run at the slipped level (cycles that
alternate between the two are an intermittent slip, ``intermittent._at_acceptance``), and nothing else at grasp
moved there (``_moved_otherwise``), the slip is gone from that cycle: the offset is read from zero there and the
tool point at grasp from where the refitted tool puts it (a new slip from the clean level still alarms), and the
diagnosis says the baseline held it instead of naming a fault. Only the axes the slip moved (the baseline's offset
more than ``BETWEEN`` scales off zero) are read so: an axis at its clean level in the baseline, a scale off zero by
its noise, moved to zero walked its CUSUM to an alarm over a long run.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.diagnose.baseline import Baseline, feature_matrix
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.intermittent import AT_ZERO, BETWEEN, MIN_HITS, OUTLIER, nearer_level

TOOL_POINT = "grasp_tcp_"  # the tool point at grasp: the part less its offset, so the offset's change moves it back
SEEN = ("part_seen_", "fixture_seen_")  # where the camera saw the part and the fixture: no tool moves them


@dataclass(frozen=True)
class SlipGone:
    """The slip the baseline holds, gone from ``cycle`` on: per offset axis the slip moved, the baseline's level and
    the median reading from ``cycle`` on [mm]."""

    cycle: int
    signals: tuple[str, ...]
    held: tuple[float, ...]
    back: tuple[float, ...]
    slipped: tuple[int, int] | None = None  # the first and last watched cycle at the slipped level, if any

    def words(self) -> str:
        before = f" (cycles {self.slipped[0]} to {self.slipped[1]} read the slipped level)" if self.slipped else ""
        held, back = _mm(self.signals, self.held), _mm(self.signals, self.back)
        return (f"the acceptance baseline holds a slipped tool (part-to-tool offset at grasp {held}, where a tool "
                f"that holds its place reads 0); from cycle {self.cycle} on it reads {back}{before}: the slip is "
                "gone, not a new one; the offset is watched from 0 there. Take the baseline from a record whose "
                "tool held its place (--acceptance DIR)")

    def read_words(self) -> str:
        """Evidence for a slip found after this one was gone: what its change is read from."""
        return (f"read from 0, where a tool that holds its place reads: the acceptance baseline holds a slipped tool "
                f"({_mm(self.signals, self.held)}), back in place from cycle {self.cycle}")

    def to_dict(self) -> dict:
        return {"cycle": self.cycle, "signals": list(self.signals), "baseline_mm": [round(v, 3) for v in self.held],
                "since_mm": [round(v, 3) for v in self.back], "slipped_cycles": self.slipped and list(self.slipped),
                "why": self.words()}


def _mm(signals: Sequence[str], values: Sequence[float]) -> str:
    return ", ".join(f"{v:+.1f} mm in {s.removeprefix(AT_ZERO)[0]}" for s, v in zip(signals, values))


def slip_gone(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray) -> SlipGone | None:
    """The slip ``baseline`` holds, gone in ``cycles`` (residuals ``z``, Shape (cycles, features)); None where the
    baseline holds none (no axis of the offset ``OUTLIER`` scales off zero), the offset is not back at zero on
    the last cycles, it alternated before them, or something else moved at grasp there."""
    cols = [j for j, n in enumerate(baseline.names) if n.startswith(AT_ZERO)]
    if not cols or not len(cycles):
        return None
    centre, scale = (m[:, cols] for m in baseline.centre_and_scale(cycles))
    with np.errstate(invalid="ignore"):
        if not np.any(np.all(np.abs(centre) >= OUTLIER * scale, axis=0)):
            return None
        slipped = np.all(np.abs(centre) > BETWEEN * scale, axis=0)
    cols, centre, scale = [j for j, s in zip(cols, slipped) if s], centre[:, slipped], scale[:, slipped]
    x = feature_matrix(cycles, [baseline.names[j] for j in cols]) / scale
    seen = ~np.isnan(z[:, cols]).any(axis=1) & ~np.isnan(x).any(axis=1)
    off = np.flatnonzero(seen & nearer_level(x, centre / scale))
    tail = np.flatnonzero(seen & (np.arange(len(cycles)) > (off[-1] if len(off) else -1)))
    if len(tail) < MIN_HITS or np.any(np.abs(np.median(x[tail], axis=0)) > BETWEEN):
        return None
    if np.count_nonzero(seen[:tail[0]]) > len(off):  # cycles back at zero between the slipped ones: intermittent
        return None
    gone = SlipGone(cycles[tail[0]].index, tuple(baseline.names[j] for j in cols),
                    tuple(float(v) for v in np.median(centre, axis=0)),
                    tuple(float(v) for v in np.median(x[tail] * scale[tail], axis=0)),
                    (cycles[off[0]].index, cycles[off[-1]].index) if len(off) else None)
    z = read_from_zero(baseline, cycles, z, gone)
    return None if _moved_otherwise(baseline, gone, z, off if len(off) >= MIN_HITS else off[:0], tail[:MIN_HITS]) \
        else gone


def _moved_otherwise(baseline: Baseline, gone: SlipGone, z: np.ndarray, before: np.ndarray, after: np.ndarray) -> bool:
    """Whether, read from where the refitted tool puts it (``z``), the camera-seen part or fixture or the tool point
    at grasp stepped on an axis of the slip, by more than ``BETWEEN`` scales, at the cycle it was gone: between the
    cycles ``before`` (the slipped ones; the baseline where under ``MIN_HITS``) and the first ``after`` it (a
    step later on is another change's). A fixture that moved by the slip brings the offset to zero with the tool
    still slipped, and a tool truly back in place moves the tool point back by the offset the baseline held."""
    axes = [s.removeprefix(AT_ZERO) for s in gone.signals]
    cols = [j for j, n in enumerate(baseline.names) if n.startswith((TOOL_POINT, *SEEN)) and n.endswith(tuple(axes))]
    return any(abs(_level(z[after, j]) - _level(z[before, j])) > BETWEEN for j in cols)


def _level(z: np.ndarray) -> float:
    """The median of the readings ``z`` that are read; 0, the baseline's, where none is."""
    z = z[~np.isnan(z)]
    return float(np.median(z)) if len(z) else 0.0


def centre_shift(baseline: Baseline, cycles: Sequence[Cycle], gone: SlipGone | None) -> np.ndarray:
    """How far [unit] a tool back in place moves each feature's baseline centre on each of ``cycles``, Shape (cycles,
    features): from ``gone.cycle`` on, the offset by minus the level it held (to zero) and the tool point
    (``TOOL_POINT``, the part less the offset) by that level; zero elsewhere and where nothing is gone."""
    shift = np.zeros((len(cycles), len(baseline.names)))
    if gone is None:
        return shift
    rows = np.array([c.index >= gone.cycle for c in cycles])
    centre, _ = baseline.centre_and_scale([c for c, r in zip(cycles, rows) if r])
    for name in gone.signals:
        held = np.nan_to_num(centre[:, baseline.names.index(name)])
        for other, sign in ((name, -1.0), (name.replace(AT_ZERO, TOOL_POINT), 1.0)):
            if other in baseline.names:
                shift[rows, baseline.names.index(other)] = sign * held
    return shift


def read_from_zero(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray, gone: SlipGone | None) -> np.ndarray:
    """``z`` with the cycles from ``gone.cycle`` on read from where a tool in its place puts them, not from the
    baseline's slipped tool (``centre_shift``; ``z`` itself where nothing is gone)."""
    if gone is None:
        return z
    _, scale = baseline.centre_and_scale(cycles)
    return z - centre_shift(baseline, cycles, gone) / scale
