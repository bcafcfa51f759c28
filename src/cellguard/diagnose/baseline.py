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
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.feature_kinds import NOT_MONITORED, kind_of, scale_floor
from cellguard.diagnose import steady
from cellguard.errors import RecordError
from cellguard.output import keep_output
from cellguard.record.json_values import loads

MAD_TO_SIGMA = 1.4826
LOAD_FEATURE = "grasped"
# how a baseline's scales are taken: 1 winsorised every acceptance (5 cycles clipped the one honest reading: a
# healthy arm named part_misplaced); 2 not below 10 cycles, and bounded so a scale reads low at most 5 % of the time
METHOD = 2
OWN_SOURCE = "acceptance cycles of this record"
MIN_CYCLES = 5
BINDING_KEYS = ("robot", "profile_sha256", "record_id", "epoch_wall_ns")  # the epoch: a record without an id's
WINSORISE_FROM = 10  # acceptance cycles: fewer, and one odd cycle is as likely honest as not
SIGMA_LEVEL = 0.05  # a scale from few cycles reads below the true sigma this seldom



class TooFewCycles(RecordError):
    """A record with too few cycles to diagnose: too few acceptance cycles for a baseline (``baseline``), or no
    production cycle to compare with it (an excitation record's one cycle). A pooling of many records leaves such a
    one out, not one whose baseline is another record's (every run's is that one)."""

    def __init__(self, message: str, baseline: bool = False):
        super().__init__(message)
        self.baseline = baseline

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
    source: str = OWN_SOURCE
    bound_to: Mapping[str, str | None] = field(default_factory=dict)  # robot, profile_sha256, record_id
    trends: Mapping[str, float] = field(default_factory=dict)  # features not steady in acceptance: their change
    # those of the trends that stepped, and the cycle it began; None: not told (a file written before steps were)
    steps: Mapping[str, int] | None = field(default_factory=dict)
    method: int = METHOD  # how the scales were taken (a file without one: 1, before the small-sample bound)

    def bind(self, context: Mapping) -> Baseline:
        """This baseline bound to the record whose ``context`` it came from."""
        return replace(self, bound_to=binding_of(context))

    def check_binding(self, context: Mapping, path: object) -> None:
        """Refuse to apply this baseline to a record other than the one it came from (robot, profile,
        record id; for a format-1 record, which has no id, its run's epoch). A key the record lacks, as in records
        written before it existed, is not compared; one the record has must be the baseline's too: a baseline that
        does not say where it came from (edited, or written before baselines were bound) is refused, but for the
        epoch (``unbound_epoch``: the caller checks such a baseline against the record's own acceptance)."""
        mine = binding_of(context)
        advice = "delete it to rebuild it from this record's acceptance cycles, or pass --acceptance DIR"
        for key in BINDING_KEYS:
            value = self.bound_to.get(key)
            if mine[key] is not None and value is not None and mine[key] != value:
                raise RecordError(f"{path}: baseline is bound to {key} {value!r}, this record has {mine[key]!r}; "
                                  f"{advice}")
        unbound = [k for k in BINDING_KEYS[:-1] if mine[k] is not None and self.bound_to.get(k) is None]
        if unbound:
            raise RecordError(f"{path}: baseline does not name the {' and '.join(unbound)} it came from (edited, or "
                              f"written before baselines were bound to their record); {advice}")

    def unbound_epoch(self, context: Mapping) -> bool:
        """Whether this baseline of a format-1 record (no record id) does not name the run's epoch: one written
        before baselines did, of this record or of any other run of the same robot and profile."""
        return binding_of(context)["epoch_wall_ns"] is not None and self.bound_to.get("epoch_wall_ns") is None

    def same_acceptance(self, other: Baseline) -> bool:
        """Whether ``other`` was taken from the same acceptance cycles: the same cycles, features and medians (the
        scales are not compared: an earlier ``method`` took them otherwise from the same cycles)."""
        return (self.names, self.cycles, self.n, set(self.motions)) == (other.names, other.cycles, other.n,
                                                                       set(other.motions)) and all(
            np.allclose(m.median, other.motions[k].median, rtol=1e-9, atol=0) for k, m in self.motions.items())

    def check_fits(self, cycles: Sequence[Cycle], path: object) -> None:
        """Refuse a baseline that cannot watch these cycles: most of its features absent from them (or most
        of theirs absent from it), or a motion of theirs it has no statistics for (those cycles would go
        unwatched)."""
        names = set(self.names)
        seen = {k for c in cycles for k in c.features} - NOT_MONITORED
        for missing, total, what in ((sorted(names - seen), len(names), "of the baseline's features are not "
                                      "in this record"),
                                     (sorted(seen - names), len(seen), "of this record's features are not in "
                                      "the baseline")):
            if total and len(missing) > total / 2:
                raise RecordError(f"{path}: baseline is of another cell: {len(missing)} of {total} {what} "
                                  f"({', '.join(missing[:3])}, ...)")
        if "" in self.motions:
            return
        unwatched: dict[str, int] = {}
        for c in cycles:
            if (c.label or "") not in self.motions:
                unwatched[c.label or ""] = unwatched.get(c.label or "", 0) + 1
        if unwatched:
            label, count = next(iter(unwatched.items()))
            raise RecordError(f"{path}: baseline has no statistics for motion {label!r} ({count} of this record's "
                              f"{len(cycles)} cycles), only for {', '.join(repr(k) for k in self.motions)}")

    @classmethod
    def from_cycles(cls, cycles: Sequence[Cycle], source: str = OWN_SOURCE) -> Baseline:
        """Baseline of ``cycles`` (the acceptance phase); at least MIN_CYCLES per motion."""
        why = too_few(cycles)
        if why is not None:
            raise TooFewCycles(f"baseline: {why}", baseline=True)
        names = sorted({k for c in cycles for k in c.features} - NOT_MONITORED)
        motions, most, at = {}, {}, {}
        for label in sorted({c.label or "" for c in cycles}):
            group = [c for c in cycles if (c.label or "") == label]
            x = feature_matrix(group, names)
            motions[label] = _stats(names, x)
            for k, v in steady.trends(names, x).items():
                if v.step_at is not None:  # each motion's first cycle at the new level: it began by the earliest
                    at[k] = min(at.get(k, group[v.step_at].index), group[v.step_at].index)
                if abs(v.change) > abs(most[k].change if k in most else 0.0):  # the motion that moved it most
                    most[k] = v  # tells how it moved
        moved = {k: v.change for k, v in most.items()}
        steps = {k: at[k] for k, v in sorted(most.items()) if v.step_at is not None}
        x = feature_matrix(cycles, names)
        load = float(np.nanmedian(x[:, names.index(LOAD_FEATURE)])) if LOAD_FEATURE in names else None
        return cls(tuple(names), motions, (cycles[0].index, cycles[-1].index), len(cycles), load, source,
                   trends=moved, steps=steps)

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
        """Standardised residuals ``(x - median) / scale``, Shape (cycles, features); NaN = no reading, as are the
        load-dependent features on the cycles ``other_load`` names (read against another load's baseline)."""
        centre, scale = self.centre_and_scale(cycles)
        z = (feature_matrix(cycles, self.names) - centre) / scale
        other = set(self.other_load(cycles))
        other_load = np.array([c.index in other for c in cycles], dtype=bool)
        if other_load.any():
            dependent = np.array([kind_of(n).load for n in self.names])
            z[np.ix_(other_load, dependent)] = np.nan
        return z

    def other_load(self, cycles: Sequence[Cycle]) -> list[int]:
        """The cycles that carried another load than the acceptance (no part grasped, say): their load-dependent
        features (currents, tracking) are not watched, so a joint fault on those cycles goes unseen."""
        if self.load is None:
            return []
        return [c.index for c in cycles if c.features.get(LOAD_FEATURE, self.load) != self.load]

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
                "bound_to": dict(self.bound_to), "names": list(self.names), "motions": {k: m.to_dict(self.names) for k, m in self.motions.items()},
                "trends": dict(self.trends), "steps": None if self.steps is None else dict(self.steps),
                "method": self.method}

    @classmethod
    def from_dict(cls, raw: object) -> Baseline:
        """A baseline as ``to_dict`` wrote it; RecordError ("baseline: malformed: FIELD ...") on anything
        that could not have come from acceptance cycles (it would blind the diagnosis, not fail it)."""
        try:
            if not isinstance(raw, Mapping):
                raise RecordError(f"baseline: malformed: the file holds {type(raw).__name__}, not an object")
            _require(raw, ("names", "motions", "cycles", "n"), "the file")
            if "source" not in raw:  # every cellguard wrote it; whose acceptance it is decides which cycles are watched
                raise RecordError("baseline: malformed: the file has no source (whose acceptance cycles it holds; "
                                  "edited or hand-made): delete it to rebuild it from the record's acceptance cycles")
            names = _names(raw["names"])
            if not isinstance(raw["motions"], Mapping):
                raise RecordError("baseline: malformed: motions must be an object of each motion's statistics")
            if not raw["motions"]:  # drift is judged against the motions' statistics: none, nothing to judge by
                raise RecordError("baseline: malformed: motions is empty")
            motions = {_text(label, "a motion's label", empty=True): _motion(label, m, names)
                       for label, m in raw["motions"].items()}
            cycles, n = _cycles_and_n(raw["cycles"], raw["n"], motions)
            if not isinstance(raw.get("bound_to") or {}, Mapping):
                raise RecordError("baseline: malformed: bound_to must be an object (robot, profile_sha256, record_id)")
            bound = {str(k): (None if v is None else str(v)) for k, v in dict(raw.get("bound_to") or {}).items()}
            method = raw.get("method", 1)
            if isinstance(method, bool) or not isinstance(method, int) or not 1 <= method <= METHOD:
                raise RecordError(f"baseline: malformed: method must be an integer from 1 to {METHOD}, got {method!r}")
            trends = _trends(raw.get("trends") or {}, names)
            return cls(names, motions, cycles, n, _load(raw.get("load"), names),
                       _text(raw["source"], "source"), bound, trends,
                       _steps(raw.get("steps"), trends, cycles), method)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise RecordError(f"baseline: malformed ({exc.__class__.__name__}: {exc})") from None

    def save(self, path: Path) -> None:
        keep_output(Path(path), json.dumps(self.to_dict(), indent=1), "baseline")  # not rewritten unchanged

    @classmethod
    def load(cls, path: Path) -> Baseline:
        try:
            raw = loads(Path(path).read_text())
        except (OSError, ValueError) as exc:  # ValueError: not JSON, or nested past json_values.MAX_DEPTH
            raise RecordError(f"{path}: cannot read the baseline ({exc.__class__.__name__})") from None
        try:
            return cls.from_dict(raw)
        except RecordError as exc:
            raise RecordError(f"{path}: {exc}") from None


def _text(value: object, where: str, empty: bool = False) -> str:
    if not isinstance(value, str) or not (empty or value.strip()):
        raise RecordError(f"baseline: malformed: {where} must be {'' if empty else 'non-empty '}text, "
                          f"got {value!r:.40}")
    return value


def _require(raw: Mapping, keys: Sequence[str], where: str) -> None:
    missing = [k for k in keys if k not in raw]
    if missing:
        raise RecordError(f"baseline: malformed: {where} has no {', '.join(missing)}")


def _names(raw: object) -> tuple[str, ...]:
    if not isinstance(raw, list) or not raw:
        raise RecordError(f"baseline: malformed: names must be a non-empty list of feature names, got {raw!r:.60}")
    names = tuple(_text(v, f"names[{i}]") for i, v in enumerate(raw))
    twice = sorted({v for v in names if names.count(v) > 1})
    if twice:
        raise RecordError(f"baseline: malformed: names lists {', '.join(map(repr, twice))} more than once")
    return names


def _number(value: object, where: str, positive: bool = False) -> float:
    try:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    except OverflowError:  # an integer past any float
        ok = False
    if not ok or (positive and value <= 0.0):
        raise RecordError(f"baseline: malformed: {where} must be a {'positive ' if positive else ''}finite number, "
                          f"got {value!r:.40}")
    return float(value)


def _count(value: object, where: str, least: int) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < least:
        raise RecordError(f"baseline: malformed: {where} must be a whole number of at least {least}, "
                          f"got {value!r:.40}")
    return value


def _motion(label: str, m: object, names: tuple[str, ...]) -> MotionStats:
    where = f"motions.{label or '(all)'}"
    if not isinstance(m, Mapping):
        raise RecordError(f"baseline: malformed: {where} must be an object, got {type(m).__name__}")
    _require(m, ("n", "features", "correlation"), where)
    feats, corr = m["features"], m["correlation"]
    if not isinstance(feats, Mapping):
        raise RecordError(f"baseline: malformed: {where}.features must be an object")
    for k in names:
        if not isinstance(feats.get(k), Mapping):
            raise RecordError(f"baseline: malformed: {where}.features.{k} is missing (names lists it)")
    median = tuple(_number(feats[k].get("median"), f"{where}.features.{k}.median") for k in names)
    scale = tuple(_number(feats[k].get("scale"), f"{where}.features.{k}.scale", positive=True) for k in names)
    p = len(names)
    if not isinstance(corr, list) or len(corr) != p or any(not isinstance(r, list) or len(r) != p for r in corr):
        raise RecordError(f"baseline: malformed: {where}.correlation is not {p} x {p}")
    c = np.array([[_number(v, f"{where}.correlation") for v in r] for r in corr])
    if not (np.allclose(c, c.T, atol=1e-9) and np.allclose(np.diag(c), 1.0, atol=1e-9) and _positive_definite(c)):
        raise RecordError(f"baseline: malformed: {where}.correlation is not a correlation matrix (symmetric, "
                          "unit diagonal, positive definite)")
    return MotionStats(_count(m["n"], f"{where}.n", MIN_CYCLES), median, scale,
                       tuple(tuple(float(v) for v in r) for r in c))


def _positive_definite(c: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return False
    return True


def _cycles_and_n(cycles: object, n: object, motions: Mapping[str, MotionStats]) -> tuple[tuple[int, int], int]:
    if not isinstance(cycles, list) or len(cycles) != 2:
        raise RecordError(f"baseline: malformed: cycles must be [first, last], got {cycles!r:.40}")
    first, last = (_count(v, "cycles", 0) for v in cycles)
    if first > last:
        raise RecordError(f"baseline: malformed: cycles must be [first, last], got {cycles!r:.40}")
    n = _count(n, "n", MIN_CYCLES)
    if n != sum(m.n for m in motions.values()) or n > last - first + 1:
        raise RecordError(f"baseline: malformed: n ({n}) is not the motions' cycles "
                          f"({sum(m.n for m in motions.values())}) within cycles {first} to {last}")
    return (first, last), n


def _trends(raw: object, names: tuple[str, ...]) -> dict[str, float]:
    """The stored trends of the acceptance cycles (absent in baselines written before they were kept)."""
    if not isinstance(raw, Mapping) or not set(raw) <= set(names):
        raise RecordError("baseline: malformed: trends must be an object of the names' changes over the acceptance")
    return {k: _number(v, f"trends.{k}") for k, v in raw.items()}


def _steps(raw: object, trends: Mapping[str, float], cycles: tuple[int, int]) -> dict[str, int] | None:
    """The stored steps of the trends, each at a cycle a step can begin at (``steady.SIDE`` acceptance cycles on
    either side); None where the file has none (written before steps were told from trends: its trends are told
    neither way)."""
    if raw is None:
        return None
    if not isinstance(raw, Mapping):
        raise RecordError(f"baseline: malformed: steps must be an object of the trends' features and the cycle each "
                          f"stepped at, got {raw!r:.40}")
    stray = sorted(set(raw) - set(trends))
    if stray:
        raise RecordError(f"baseline: malformed: steps.{stray[0]:.60} is not among the trends")
    first, last = cycles[0] + steady.SIDE, cycles[1] - steady.SIDE + 1
    at = {k: _count(v, f"steps.{k}", first) for k, v in raw.items()}
    late = sorted(k for k, v in at.items() if v > last)
    if late:
        raise RecordError(f"baseline: malformed: steps.{late[0]} must be at most {last} ({steady.SIDE} acceptance "
                          f"cycles after a step), got {at[late[0]]}")
    return at


def too_few(cycles: Sequence[Cycle]) -> str | None:
    """Why the acceptance ``cycles`` give no baseline, None if they give one: MIN_CYCLES of each motion, so a cell
    that alternates its motions needs that many times its motions in all (the count to give a run)."""
    if len(cycles) < MIN_CYCLES:
        return f"needs at least {MIN_CYCLES} acceptance cycles, got {len(cycles)}"
    counts = Counter(c.label or "" for c in cycles)
    short = sorted(k for k, n in counts.items() if n < MIN_CYCLES)
    if not short:
        return None
    split = ", ".join(f"{k or '(none)'} {n}" for k, n in sorted(counts.items()))
    return (f"needs at least {MIN_CYCLES} acceptance cycles of motion {short[0]!r}, got {counts[short[0]]} (of the "
            f"{len(cycles)}: {split}); each of the {len(counts)} motions needs {MIN_CYCLES}: at least "
            f"{MIN_CYCLES * len(counts)} acceptance cycles where they alternate")


def _load(value: object, names: tuple[str, ...]) -> float | None:
    if value is None and LOAD_FEATURE not in names:
        return None
    return _number(value, "load")


def check_same_robot(acceptance: Mapping, context: Mapping, path: object, record: object) -> None:
    """Refuse an acceptance record (its context ``acceptance``, at ``path``) of another robot or embodiment
    profile than the ``record`` diagnosed (its ``context``); a key either lacks (older records) is not
    compared."""
    theirs, mine = binding_of(acceptance), binding_of(context)
    for key in ("robot", "profile_sha256"):
        if theirs[key] is not None and mine[key] is not None and theirs[key] != mine[key]:
            raise RecordError(f"{path}: is a record of {key} {theirs[key]!r}, {record} has {mine[key]!r}; "
                              "take the baseline from a record of the same robot and profile")


def binding_of(context: Mapping) -> dict[str, str | None]:
    """What ties a baseline to its record: robot, embodiment profile hash and record id, or where a record has
    none (format 1) its run's epoch (``epoch_wall_ns``, wall clock at its start, kept by a copy); None when the
    context does not carry it."""
    emb = context.get("embodiment") if isinstance(context.get("embodiment"), Mapping) else {}
    rec = context.get("record") if isinstance(context.get("record"), Mapping) else {}
    record_id = context.get("record_id") or rec.get("record_id") or rec.get("id")
    epoch = None if record_id else context.get("epoch_wall_ns") or None  # 0: lost
    values = {"robot": emb.get("robot"), "profile_sha256": emb.get("sha256"), "record_id": record_id,
              "epoch_wall_ns": epoch}
    return {k: (None if v is None else str(v)) for k, v in values.items()}


def feature_matrix(cycles: Sequence[Cycle], names: Sequence[str]) -> np.ndarray:
    """Features as a float64 array, Shape (cycles, names); a missing reading is NaN."""
    x = np.full((len(cycles), len(names)), np.nan)
    for i, c in enumerate(cycles):
        f = c.features
        x[i] = [f.get(n, np.nan) for n in names]
    return x


def robust_sigma(x: np.ndarray) -> np.ndarray:
    """Per column, a sigma from few cycles that does not read low: the larger of the MAD estimate and
    the standard deviation (winsorised at 3 MAD-sigmas from ``WINSORISE_FROM`` cycles on; below, the MAD
    of a handful of cycles is itself noise and clipped an honest one), times the larger of
    ``1 + 2 / sqrt(n)`` and the upper ``SIGMA_LEVEL`` confidence bound of a sigma from ``n`` cycles
    (chi-square), the latter widened for the error of a median centre from ``n`` cycles. From about
    17 cycles on the first factor is the larger; at 5 cycles the second is 2.7, not 1.9 (five
    cycles of a part placed with 0.25 mm of noise read 0.05 mm with the first alone)."""
    med = np.nanmedian(x, axis=0)
    mad = MAD_TO_SIGMA * np.nanmedian(np.abs(x - med), axis=0)
    n = np.maximum(np.sum(~np.isnan(x), axis=0), 2)
    reach = np.where(n >= WINSORISE_FROM, 3.0 * mad, np.inf)
    wins = np.nanstd(np.clip(x, med - reach, med + reach), axis=0, ddof=1)
    bound = np.sqrt((n - 1) / chi2.ppf(SIGMA_LEVEL, n - 1) * (1.0 + np.pi / (2.0 * n)))
    return np.fmax(mad, wins) * np.fmax(1.0 + 2.0 / np.sqrt(n), bound)


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
