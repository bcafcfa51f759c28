"""Mirrored-motion asymmetry: each motion against its mirror, for cells with a symmetry map.

A left turn on the left legs should look like a right turn on the right legs. So a per-joint
feature of a left joint in a left turn is compared with the same feature of its mirror joint
in a right turn (and the other way round); per-leg features (contact duty, step timing) use
the legs the symmetry map implies (``fl_hip``/``fr_hip`` -> legs ``fl``/``fr``). Motion-level
features (yaw rate reached over commanded) are compared between the two mirrored motions.
No baseline is needed: the robot is its own reference, so a fault present since acceptance
still shows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellguard.diagnose.baseline import MAD_TO_SIGMA
from cellguard.diagnose.feature_kinds import scale_floor
from cellguard.diagnose.cycles import Cycle
from cellguard.embodiment.profile import SymmetryPair

MIRROR_LABEL = {"left": "right", "right": "left"}
MOTION_FEATURES = ("yaw_rate_ratio", "speed_reached", "cycle_time_s")
MIN_RELATIVE = 0.05  # a mirrored difference below 5 % is not an asymmetry
MIN_T = 4.0  # and it must stand this many standard errors above the cycle-to-cycle noise
# Not compared across mirrored members: the extremes (one sample per cycle, too phase-dependent) and the
# friction torque (on a leg the ground's share of the drive's work shifts with the gait, so mirrored
# legs differ by several percent in a healthy robot).
UNMIRRORED = ("current_peak", "tracking_max", "friction_torque")


@dataclass(frozen=True)
class MirrorDifference:
    """``feature`` on the left member against its mirror; ``relative`` = (left - right) / mean."""

    feature: str
    left: str  # e.g. "tracking_rms.fl_hip during left turns"
    right: str
    left_value: float
    right_value: float
    relative: float
    t: float  # difference over its standard error
    mirror: str = ""  # the mirror member's feature (``tracking_rms.fr_hip``)
    turns: tuple[str, str] = ("", "")  # the motions each side was read in ("" where not split by motion)

    @property
    def significant(self) -> bool:
        return abs(self.relative) >= MIN_RELATIVE and abs(self.t) >= MIN_T

    def to_dict(self) -> dict:
        return {"feature": self.feature, "left": self.left, "right": self.right,
                "left_value": round(self.left_value, 6), "right_value": round(self.right_value, 6),
                "relative": round(self.relative, 4), "t": round(self.t, 1)}


@dataclass(frozen=True)
class Asymmetry:
    """The side that differs (``left``, ``right`` or None), its joints, and every comparison."""

    side: str | None
    joints: tuple[str, ...]
    differences: tuple[MirrorDifference, ...]
    evidence: tuple[str, ...]

    @property
    def significant(self) -> tuple[MirrorDifference, ...]:
        return tuple(d for d in self.differences if d.significant)

    @property
    def what(self) -> tuple[str, ...]:
        """What differs, in words: the side's joints, else (a gait, on no joint) the measures that differ."""
        return self.joints or tuple(sorted({d.feature.rsplit(".", 1)[0] for d in self.significant}))

    @property
    def where(self) -> str:
        """Where mirrored motions differ, in words: on a side, else between the motions (no side told)."""
        return f"on the {self.side} side" if self.side else "between the motions, on no side a joint or leg tells"

    def to_dict(self) -> dict:
        return {"side": self.side, "joints": list(self.joints), "evidence": list(self.evidence),
                "differences": [d.to_dict() for d in self.significant]}


def mirror_map(pairs: Sequence[SymmetryPair]) -> dict[str, str]:
    """Left member -> right member, for joints and for the legs their names imply."""
    out = {p.left: p.right for p in pairs}
    for p in pairs:
        a, b = p.left, p.right
        n = 0
        while n < min(len(a), len(b)) and a[len(a) - 1 - n] == b[len(b) - 1 - n]:
            n += 1
        if 0 < n < min(len(a), len(b)):
            out.setdefault(a[: len(a) - n].rstrip("_"), b[: len(b) - n].rstrip("_"))
    return out


def mirrored_asymmetry(cycles: Sequence[Cycle], pairs: Sequence[SymmetryPair]) -> Asymmetry | None:
    """Compare mirrored motions over ``cycles``; None when the cell has no symmetry map."""
    if not pairs or not cycles:
        return None
    mirror = mirror_map(pairs)
    joints = {p.left for p in pairs} | {p.right for p in pairs}
    labels = sorted({c.label for c in cycles if c.label in MIRROR_LABEL})
    groups = {lab: [c for c in cycles if c.label == lab] for lab in labels} if len(labels) == 2 else {"": cycles}
    names = sorted({k for c in cycles for k in c.features})
    diffs: list[MirrorDifference] = []
    for name in names:
        kind, _, member = name.partition(".")
        if kind in UNMIRRORED or member not in mirror or f"{kind}.{mirror[member]}" not in names:
            continue
        other = f"{kind}.{mirror[member]}"
        for lab, group in groups.items():
            mirror_group = groups[MIRROR_LABEL[lab]] if lab else group
            suffix = f" during {lab} turns" if lab else ""
            mirror_suffix = f" during {MIRROR_LABEL[lab]} turns" if lab else ""
            d = _compare(name, other, group, mirror_group, f"{name}{suffix}", f"{other}{mirror_suffix}",
                         (lab, MIRROR_LABEL[lab] if lab else ""))
            if d is not None:
                diffs.append(d)
    if len(labels) == 2:
        for name in MOTION_FEATURES:
            if name in names:
                d = _compare(name, name, groups["left"], groups["right"], f"{name} in left turns",
                             f"{name} in right turns", ("left", "right"))
                if d is not None:
                    diffs.append(d)
    return _judge(tuple(diffs), mirror, joints)


def _compare(a: str, b: str, ga: Sequence[Cycle], gb: Sequence[Cycle], la: str, lb: str,
             turns: tuple[str, str] = ("", "")) -> MirrorDifference | None:
    x = np.array([c.features[a] for c in ga if a in c.features])
    y = np.array([c.features[b] for c in gb if b in c.features])
    if len(x) < 2 or len(y) < 2:
        return None
    mx, my = float(np.median(x)), float(np.median(y))
    mean = 0.5 * (abs(mx) + abs(my))
    if mean < 1e-9 or abs(abs(mx) - abs(my)) < 2.0 * scale_floor(a, mean):
        return None  # smaller than a change that matters for this kind of feature
    sx, sy = (max(MAD_TO_SIGMA * float(np.median(np.abs(v - np.median(v)))), 0.005 * mean) for v in (x, y))
    se = 1.2533 * np.sqrt(sx * sx / len(x) + sy * sy / len(y))  # standard error of a median
    return MirrorDifference(a, la, lb, mx, my, (abs(mx) - abs(my)) / mean, (abs(mx) - abs(my)) / se, b, turns)


def asymmetry_onset(cycles: Sequence[Cycle], asym: Asymmetry, pairs: Sequence[SymmetryPair], first: int) -> int:
    """The cycle the asymmetry ``asym`` (found over the watched cycles, the first of which is ``first``)
    began, from ``cycles`` (acceptance and watched, in order): the change point of its significant
    mirrored differences, cycle by cycle (each cycle reads one side of each difference, or both where
    the motions are not split), where the cycles before it hold no asymmetry on that side. ``first``
    where the asymmetry was there before (or no change point stands out)."""
    sig = asym.significant
    if not sig or not asym.side:
        return first
    rows = []
    for d in sig:
        x = _side_series(cycles, d.feature, d.turns[0])
        y = _side_series(cycles, d.mirror or d.feature, d.turns[1])
        mean = 0.5 * (abs(d.left_value) + abs(d.right_value))
        rows.append(np.sign(d.relative) * (np.nan_to_num(x) - np.nan_to_num(y)) / mean)
    s = np.mean(rows, axis=0)
    if len(s) < 4:
        return first
    cusum = np.cumsum(s - s.mean())[:-1]  # the least-squares split of one step in the mean
    k = int(np.argmax(np.abs(cusum))) + 1
    onset = cycles[k].index
    if onset <= first:
        return first
    if held_before(cycles, asym, pairs, onset):
        return first  # the cycles before hold it already: it was there from the start
    return onset


def held_before(cycles: Sequence[Cycle], asym: Asymmetry, pairs: Sequence[SymmetryPair], cycle: int) -> bool:
    """Whether the cycles of ``cycles`` before ``cycle`` differ on the side of ``asym`` already. Before the first
    watched cycle (an acceptance of its own record): the asymmetry is there from the first cycle recorded, and no
    cycle of the record is a good one to compare with."""
    before = mirrored_asymmetry([c for c in cycles if c.index < cycle], pairs)
    return before is not None and before.side == asym.side


def _side_series(cycles: Sequence[Cycle], name: str, turn: str) -> np.ndarray:
    """|``name``| per cycle in motion ``turn`` ("" any), minus its median; 0 on the other cycles."""
    v = np.array([abs(c.features[name]) if name in c.features and (not turn or c.label == turn) else np.nan
                  for c in cycles])
    return v - np.nanmedian(v) if np.isfinite(v).any() else np.zeros(len(cycles))


def _judge(diffs: tuple[MirrorDifference, ...], mirror: dict[str, str], joint_names: set[str]) -> Asymmetry:
    """Name the side whose joints track worse than their mirrors (else whose members differ most often, each
    comparison a vote by its sign), and its joints whose comparisons point to it, and say by how much. No side
    where nothing votes or the votes tie: the motion features alone (yaw rate reached) do not tell it, as a weaker
    servo makes its side's turns overshoot on the quadruped and friction makes them fall short."""
    sig = sorted((d for d in diffs if d.significant), key=lambda d: -abs(d.relative))
    members = [d for d in sig if "." in d.feature]
    vote = sum(np.sign(d.relative) for d in members if d.feature.startswith("tracking_"))
    vote = vote or sum(np.sign(d.relative) for d in members)
    side = "left" if vote > 0 else "right" if vote < 0 else None
    toward = [d for d in members if np.sign(d.relative) == np.sign(vote)]  # none where no side
    joints: list[str] = []
    for d in toward:
        member = d.feature.split(".", 1)[1]
        name = member if side == "left" else mirror.get(member, member)
        if name not in joints and name in joint_names:
            joints.append(name)
    evidence = [f"{d.left} {d.left_value:.4g} vs {d.right} {d.right_value:.4g} ({d.relative * 100:+.0f} %)"
                for d in sig[:8]]
    if sig:
        evidence.insert(0, _header(side, sig, [d for d in members if d not in toward]))
    return Asymmetry(side, tuple(joints), diffs, tuple(evidence))


def _header(side: str | None, sig: list[MirrorDifference], against: list[MirrorDifference]) -> str:
    """The first line of an asymmetry's evidence: the side and how many comparisons, and those of members that
    point the other way (their joints not named), or why no side is named."""
    if side is None:
        return (f"mirrored motions differ in {len(sig)} comparison(s), which side they do not tell "
                f"({'as many members each way' if against else 'no joint or leg differs'})")
    other = sorted({d.feature for d in against})
    return f"the {side} side differs from its mirror in {len(sig)} comparison(s)" + (
        f"; {len(against)} point to the {MIRROR_LABEL[side]} side, not named: {', '.join(other[:4])}"
        f"{' ...' if len(other) > 4 else ''}" if against else "")
