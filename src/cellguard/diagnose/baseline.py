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
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.feature_kinds import NOT_MONITORED, kind_of, scale_floor
from cellguard.errors import RecordError
from cellguard.output import write_output

MAD_TO_SIGMA = 1.4826
LOAD_FEATURE = "grasped"
MIN_CYCLES = 5


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
    bound_to: Mapping[str, str | None] = field(default_factory=dict)  # robot, profile_sha256, record_id

    def bind(self, context: Mapping) -> Baseline:
        """This baseline bound to the record whose ``context`` it came from."""
        return replace(self, bound_to=binding_of(context))

    def check_binding(self, context: Mapping, path: object) -> None:
        """Refuse to apply this baseline to a record other than the one it came from (robot, profile,
        record id; a key either side lacks, as in records written before it existed, is not compared)."""
        mine = binding_of(context)
        for key, value in self.bound_to.items():
            if value is not None and mine.get(key) is not None and mine[key] != value:
                raise RecordError(f"{path}: baseline is bound to {key} {value!r}, this record has {mine[key]!r}; "
                                  "delete it or pass --acceptance DIR")

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
            dependent = np.array([kind_of(n).load for n in self.names])
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
                "bound_to": dict(self.bound_to), "names": list(self.names), "motions": {k: m.to_dict(self.names) for k, m in self.motions.items()}}

    @classmethod
    def from_dict(cls, raw: dict) -> Baseline:
        try:
            names = tuple(raw["names"])
            if not raw["motions"]:  # drift is judged against the motions' statistics: none, nothing to judge by
                raise ValueError("motions is empty")
            motions = {}
            for label, m in raw["motions"].items():
                feats, corr = m["features"], m["correlation"]
                if len(corr) != len(names) or any(len(r) != len(names) for r in corr):
                    raise ValueError(f"motion {label!r}: correlation is not {len(names)} x {len(names)}")
                scales = tuple(float(feats[k]["scale"]) for k in names)
                for k, v in zip(names, scales):
                    if not (np.isfinite(v) and v > 0.0):
                        raise RecordError(f"baseline: motions.{label or '(all)'}.features.{k}.scale must be a "
                                          f"positive finite number, got {v}")
                motions[label] = MotionStats(int(m["n"]), tuple(float(feats[k]["median"]) for k in names), scales,
                                             tuple(tuple(float(v) for v in r) for r in corr))
            bound = {str(k): (None if v is None else str(v)) for k, v in dict(raw.get("bound_to") or {}).items()}
            return cls(names, motions, tuple(raw["cycles"]), int(raw["n"]), raw.get("load"),
                       raw.get("source", "stored baseline"), bound)
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


def binding_of(context: Mapping) -> dict[str, str | None]:
    """What ties a baseline to its record: robot, embodiment profile hash and record id (None when
    the context does not carry it)."""
    emb = context.get("embodiment") if isinstance(context.get("embodiment"), Mapping) else {}
    rec = context.get("record") if isinstance(context.get("record"), Mapping) else {}
    record_id = context.get("record_id") or rec.get("record_id") or rec.get("id")
    values = {"robot": emb.get("robot"), "profile_sha256": emb.get("sha256"), "record_id": record_id}
    return {k: (None if v is None else str(v)) for k, v in values.items()}


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
