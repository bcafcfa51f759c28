"""The acceptance baseline: per feature a robust centre and scale, stored with the record.

Median and a MAD-based sigma so that one odd acceptance cycle does not move the baseline,
inflated for the error of a scale estimated from a few cycles. A simulated or well-repeating
cell has features that barely vary (MAD near zero); a floor on the scale, per kind of feature,
keeps noise-sized changes from reading as hundreds of sigma: a change must matter physically
before it counts.

Cells that alternate mirrored motions (left and right turns) get one set of statistics per
motion, so a left turn is compared with the left turns of acceptance.

Load normalisation: current and tracking error depend on the load carried. They are compared
only on cycles that carried the baseline's load (``grasped``); a cycle that dropped its part
says nothing about friction, and its load change shows in ``grasped`` itself.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellguard.diagnose.cycles import Cycle
from cellguard.errors import RecordError
from cellguard.output import write_output

MAD_TO_SIGMA = 1.4826
NOT_MONITORED = frozenset({"cycle"})  # identifiers, not measurements
LOAD_FEATURE = "grasped"
LOAD_DEPENDENT = ("current_", "tracking_")
MIN_CYCLES = 5


def scale_floor(name: str, median: float) -> float:
    """Smallest scale a feature may have: the size of a change that does not matter [its unit]."""
    if name.endswith("_mm"):
        return 0.05
    if name.endswith("_ms"):
        return 1.0
    if name.endswith("_s") or "_s." in name:
        return 0.002  # two servo ticks
    if name in ("interventions", "chunks_rejected", "stale_chunks"):
        return 0.5  # counts: one event is two scales
    if name in ("success", "grasped", "timed_out", "fallen"):
        return 0.25
    if name.startswith("current_"):
        return max(0.01, 0.01 * abs(median))  # [A] sensor noise, or 1 %
    if name.startswith(("tracking_", "grasp_q.")):
        return max(1e-4, 0.01 * abs(median))  # [rad] or [m]; 1 % of the usual error
    return max(1e-6, 0.01 * abs(median))


@dataclass(frozen=True)
class MotionStats:
    """Statistics of the acceptance cycles of one motion; arrays are per feature of the baseline."""

    n: int
    median: tuple[float, ...]
    scale: tuple[float, ...]
    correlation: tuple[tuple[float, ...], ...]  # shrunk, of the residuals; Shape (p, p)

    def to_dict(self, names: Sequence[str]) -> dict:
        return {"n": self.n, "features": {k: {"median": m, "scale": s}
                                          for k, m, s in zip(names, self.median, self.scale)},
                "correlation": [list(r) for r in self.correlation]}


@dataclass(frozen=True)
class Baseline:
    """Robust statistics of the acceptance cycles, per motion label ("" when a cell has none)."""

    names: tuple[str, ...]
    motions: Mapping[str, MotionStats]
    cycles: tuple[int, int]  # first and last acceptance cycle
    n: int
    load: float | None  # the usual value of ``grasped`` in acceptance, if the cell reports it
    source: str = "acceptance cycles of this record"

    @classmethod
    def from_cycles(cls, cycles: Sequence[Cycle], source: str = "acceptance cycles of this record") -> Baseline:
        """Baseline of ``cycles`` (the acceptance phase); at least MIN_CYCLES per motion."""
        if len(cycles) < MIN_CYCLES:
            raise RecordError(f"baseline: needs at least {MIN_CYCLES} acceptance cycles, got {len(cycles)}")
        names = sorted({k for c in cycles for k in c.features} - NOT_MONITORED)
        motions = {}
        for label in sorted({c.label or "" for c in cycles}):
            group = [c for c in cycles if (c.label or "") == label]
            if len(group) < MIN_CYCLES:
                raise RecordError(f"baseline: needs at least {MIN_CYCLES} acceptance cycles of motion "
                                  f"{label!r}, got {len(group)}")
            motions[label] = _stats(names, feature_matrix(group, names))
        x = feature_matrix(cycles, names)
        load = float(np.nanmedian(x[:, names.index(LOAD_FEATURE)])) if LOAD_FEATURE in names else None
        return cls(tuple(names), motions, (cycles[0].index, cycles[-1].index), len(cycles), load, source)

    def centre_and_scale(self, cycles: Sequence[Cycle]) -> tuple[np.ndarray, np.ndarray]:
        """Each cycle's baseline median and scale (its own motion's), Shape (cycles, features)."""
        p = len(self.names)
        centre, scale = np.full((len(cycles), p), np.nan), np.ones((len(cycles), p))
        for i, c in enumerate(cycles):
            stats = self.motions.get(c.label or "") or self.motions.get("")
            if stats is not None:
                centre[i], scale[i] = stats.median, stats.scale
        return centre, scale

    def residuals(self, cycles: Sequence[Cycle]) -> np.ndarray:
        """Standardised residuals ``(x - median) / scale``, Shape (cycles, features); NaN = no reading."""
        centre, scale = self.centre_and_scale(cycles)
        z = (feature_matrix(cycles, self.names) - centre) / scale
        if self.load is not None:
            other_load = np.array([c.features.get(LOAD_FEATURE, self.load) != self.load for c in cycles])
            dependent = np.array([n.startswith(LOAD_DEPENDENT) for n in self.names])
            z[np.ix_(other_load, dependent)] = np.nan
        return z

    def correlation(self) -> np.ndarray:
        """The motions' residual correlations, averaged; Shape (p, p)."""
        return np.mean([np.asarray(m.correlation) for m in self.motions.values()], axis=0)

    def median(self, name: str) -> float:
        """The feature's acceptance median (averaged over motions of their magnitudes)."""
        j = self.names.index(name)
        return float(np.mean([m.median[j] for m in self.motions.values()]))

    def scale(self, name: str) -> float:
        j = self.names.index(name)
        return float(np.mean([m.scale[j] for m in self.motions.values()]))

    def to_dict(self) -> dict:
        return {"source": self.source, "cycles": list(self.cycles), "n": self.n, "load": self.load,
                "names": list(self.names), "motions": {k: m.to_dict(self.names) for k, m in self.motions.items()}}

    @classmethod
    def from_dict(cls, raw: dict) -> Baseline:
        try:
            names = tuple(raw["names"])
            motions = {}
            for label, m in raw["motions"].items():
                feats, corr = m["features"], m["correlation"]
                if len(corr) != len(names) or any(len(r) != len(names) for r in corr):
                    raise ValueError(f"motion {label!r}: correlation is not {len(names)} x {len(names)}")
                motions[label] = MotionStats(int(m["n"]), tuple(float(feats[k]["median"]) for k in names),
                                             tuple(float(feats[k]["scale"]) for k in names),
                                             tuple(tuple(float(v) for v in r) for r in corr))
            return cls(names, motions, tuple(raw["cycles"]), int(raw["n"]), raw.get("load"),
                       raw.get("source", "stored baseline"))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise RecordError(f"baseline: malformed ({exc.__class__.__name__}: {exc})") from None

    def save(self, path: Path) -> None:
        write_output(Path(path), json.dumps(self.to_dict(), indent=1), "baseline")

    @classmethod
    def load(cls, path: Path) -> Baseline:
        try:
            raw = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise RecordError(f"{path}: cannot read the baseline ({exc.__class__.__name__})") from None
        return cls.from_dict(raw)


def feature_matrix(cycles: Sequence[Cycle], names: Sequence[str]) -> np.ndarray:
    """Features as a float64 array, Shape (cycles, names); a missing reading is NaN."""
    x = np.full((len(cycles), len(names)), np.nan)
    for i, c in enumerate(cycles):
        f = c.features
        x[i] = [f.get(n, np.nan) for n in names]
    return x


def robust_sigma(x: np.ndarray) -> np.ndarray:
    """Per column, a conservative sigma from few cycles: the larger of the MAD estimate and the
    standard deviation winsorised at 3 MAD-sigmas, times ``1 + 2 / sqrt(n)`` for the error of an
    estimate from ``n`` cycles (twenty acceptance cycles can read sigma 40 % low)."""
    med = np.nanmedian(x, axis=0)
    mad = MAD_TO_SIGMA * np.nanmedian(np.abs(x - med), axis=0)
    wins = np.nanstd(np.clip(x, med - 3.0 * mad, med + 3.0 * mad), axis=0, ddof=1)
    n = np.maximum(np.sum(~np.isnan(x), axis=0), 2)
    return np.fmax(mad, wins) * (1.0 + 2.0 / np.sqrt(n))


def _stats(names: Sequence[str], x: np.ndarray) -> MotionStats:
    med = np.nanmedian(x, axis=0)
    sigma = robust_sigma(x)
    med = np.where(np.isnan(med), 0.0, med)
    scale = np.array([max(float(m) if np.isfinite(m) else 0.0, scale_floor(n, float(c)))
                      for n, m, c in zip(names, sigma, med)])
    corr = _shrunk_correlation((x - med) / scale)
    return MotionStats(len(x), tuple(float(v) for v in med), tuple(float(v) for v in scale),
                       tuple(tuple(float(v) for v in row) for row in corr))


def _shrunk_correlation(z: np.ndarray, clip: float = 4.0) -> np.ndarray:
    """Correlation of clipped residuals, shrunk towards the identity by p / (n + p).

    A variance under 1 (a floor-dominated feature) counts as 1, so a feature that never moved
    in acceptance is not treated as perfectly predictable. Shape (p, p), positive definite.
    """
    n, p = z.shape
    zc = np.nan_to_num(np.clip(z, -clip, clip))
    zc = zc - zc.mean(axis=0)
    cov = zc.T @ zc / max(n - 1, 1)
    d = np.sqrt(np.maximum(np.diag(cov), 1.0))
    corr = cov / np.outer(d, d)
    np.fill_diagonal(corr, 1.0)
    alpha = p / (n + p)
    return (1.0 - alpha) * corr + alpha * np.eye(p)
