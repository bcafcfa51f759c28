"""Cycle features declared per cell type: name, unit, family, noise floor, load dependence.

One table, read by the baseline (scale floors, which features depend on the load), drift
(which features warm-up and a payload move) and cause (which family an alarm belongs to).
A feature name is ``stem`` or ``stem.member`` (``current_rms.elbow``, ``contact_duty.fl``);
the stem alone says what it is, so nothing reads units from name suffixes.

``floor`` is the smallest change that matters [unit]; ``relative_floor`` the same as a share of
the feature's usual value; the scale of a feature is never below either. ``load`` marks
features that change with the load carried (a heavier product variant), ``friction`` those
that change with joint friction (a cold joint after idle). A name no table declares is an
``other`` feature with a 1 % floor: a new outcome field is watched before anyone declares it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FeatureKind:
    """What a feature stem measures; ``per`` is ``joint``, ``leg`` or ``""`` (one per cycle)."""

    stem: str
    unit: str
    family: str
    floor: float = 1e-6
    relative_floor: float = 0.01
    load: bool = False
    friction: bool = False
    per: str = ""

    def scale_floor(self, median: float) -> float:
        """Smallest scale this feature may have at its usual value ``median`` [unit]."""
        return max(self.floor, self.relative_floor * abs(median))


def _joint(stem: str, unit: str, floor: float, friction: bool) -> FeatureKind:
    return FeatureKind(stem, unit, "joint", floor, 0.01, load=True, friction=friction, per="joint")


def _fixed(stem: str, unit: str, family: str, floor: float) -> FeatureKind:
    return FeatureKind(stem, unit, family, floor, 0.0)


def _xyz(stem: str, family: str) -> tuple[FeatureKind, ...]:
    return tuple(_fixed(f"{stem}_{axis}_mm", "mm", family, 0.05) for axis in "xyz")


# Every cell: drives, the policy channel and the guard's events.
COMMON = (
    _joint("current_peak", "A", 0.01, friction=True),
    _joint("current_rms", "A", 0.01, friction=True),
    _joint("current_carry_rms", "A", 0.01, friction=True),  # while a part is carried (cells that carry one)
    _joint("current_free_rms", "A", 0.01, friction=True),  # while not
    _joint("friction_torque", "N·m", 0.005, friction=True),  # work of the drive over the joint's travel
    _joint("tracking_rms", "rad", 1e-4, friction=True),  # a position servo lags more against friction
    _joint("tracking_max", "rad", 1e-4, friction=True),
    # drift's pooled channels per joint (mean residual of its current / tracking features), not cycle features
    FeatureKind("current_pooled", "scales", "joint", per="joint"),
    FeatureKind("tracking_pooled", "scales", "joint", per="joint"),
    _fixed("latency_mean_ms", "ms", "latency", 1.0),
    _fixed("latency_max_ms", "ms", "latency", 1.0),
    _fixed("stale_chunks", "count", "latency", 0.5),
    _fixed("interventions", "count", "output", 0.5),
    _fixed("chunks_rejected", "count", "output", 0.5),
    _fixed("success", "1", "outcome", 0.25),
    _fixed("timed_out", "1", "outcome", 0.25),
    _fixed("cycle_time_s", "s", "timing", 0.002),
)

ARM = (
    _fixed("grasped", "1", "outcome", 0.25),
    _fixed("place_error_mm", "mm", "outcome", 0.05),
    *_xyz("part_seen", "geometry"), *_xyz("fixture_seen", "geometry"),
    *_xyz("grasp_tcp", "geometry"), *_xyz("grasp_offset", "geometry"),
    FeatureKind("grasp_q", "rad", "geometry", 1e-4, 0.01, per="joint"),
    _fixed("grasp_time_s", "s", "timing", 0.002),
    _fixed("release_time_s", "s", "timing", 0.002),
)

QUADRUPED = (
    _fixed("fallen", "1", "outcome", 0.25),
    *(FeatureKind(s, "rad/s", "motion") for s in ("yaw_rate_command", "yaw_rate_reached")),
    FeatureKind("yaw_rate_ratio", "1", "motion"),
    FeatureKind("heading_change_rad", "rad", "motion"),
    *(FeatureKind(s, "m/s", "motion") for s in ("speed_command", "speed_reached")),
    *(FeatureKind(s, "rad", "motion") for s in ("body_roll_rad", "body_pitch_rad")),
    FeatureKind("body_height_m", "m", "motion"),
    FeatureKind("contact_duty", "1", "gait", per="leg"),
    FeatureKind("step_period_s", "s", "gait", 0.002, 0.0, per="leg"),
    FeatureKind("touchdown_lag_s", "s", "gait", 0.002, 0.0, per="leg"),
)

CELL_FEATURES: dict[str, tuple[FeatureKind, ...]] = {
    "arm-pick-place": COMMON + ARM,
    "quadruped-turns": COMMON + QUADRUPED,
}
_ALL = {k.stem: k for kinds in CELL_FEATURES.values() for k in kinds}
# identifiers, not measurements; and what recoveries did (read by the recovery cause, not by drift)
NOT_MONITORED = frozenset({"cycle", "recoveries", "recoveries_failed", "recovery_resumed", "recovery_s",
                           "recovery_arrival_s", "recovery_close_s", "after_recovery"})


def kind_of(name: str) -> FeatureKind:
    """The declared kind of feature ``name`` (``stem`` or ``stem.member``); ``other`` if undeclared."""
    stem = name.partition(".")[0]
    return _ALL.get(stem) or FeatureKind(stem, "", "other")


def scale_floor(name: str, median: float) -> float:
    """Smallest scale feature ``name`` may have at its usual value ``median`` [its unit]."""
    return kind_of(name).scale_floor(median)


def member_of(name: str) -> str:
    """The joint or leg a per-member feature belongs to (``current_rms.elbow`` -> ``elbow``), else ``""``."""
    return name.partition(".")[2]
