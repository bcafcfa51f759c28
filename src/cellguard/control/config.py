"""GuardConfig: every setting of the guard layer in one frozen value (SI); the joint limits come from the profile.

It is also the schema of a scenario's ``guard:`` section: unknown keys, wrong types and values
outside the ranges below are refused with a message that names the key.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from cellguard.embodiment.profile import SOFT_MARGIN

Box = tuple[tuple[float, float, float], tuple[float, float, float]]
# [m] no robot cell's tool point lies this far from its world origin (arms reach under 5 m): a box coordinate beyond
# is in another unit, and a box that wide turns the workspace check off (``build_guard`` checks the cell's own reach)
BOX_LIMIT_M = 100.0


class GuardConfig(BaseModel):
    """Settings of the executor and the envelope; built once, read on the servo tick, never changed."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    watchdog_s: float = Field(default=0.3, gt=0.0, le=10.0, description="policy silence before a stop [s]")
    watchdog_category: int = Field(default=2, ge=0, le=2, description="IEC 60204-1 stop category on silence")
    uncertainty_threshold: float | None = Field(default=None, ge=0.0, description="chunk uncertainty above it: gate")
    uncertainty_action: Literal["reduce", "hold"] = Field(
        default="reduce", description="reduce: reduced speed; hold: category 2 stop until it clears")
    tool_speed_max: float | None = Field(default=None, gt=0.0, le=10.0, description="[m/s] cap in normal operation")
    reduced_speed: float = Field(default=0.25, gt=0.0, le=0.25, description="[m/s], ISO 10218-1: at most 0.25")
    blend_s: float = Field(default=0.2, gt=0.0, le=1.0, description="chunk stitching blend [s]")
    box: Box | None = Field(
        default=None, description="tool-point box [[xmin, ymin, zmin], [xmax, ymax, zmax]] [m]; default: the cell's")
    soft_margin: float = Field(default=SOFT_MARGIN, ge=0.0, lt=0.5,
                               description="soft limits this fraction of each joint's range inside the hard limits")
    effort_fraction: float = Field(default=0.98, gt=0.0, le=1.0,
                                   description="measured |effort| above this fraction of the limit ...")
    effort_hold_s: float = Field(default=0.05, gt=0.0, le=1.0, description="... for at least this long, in whole "
                                 "servo samples (at least 2): category 2 stop [s]")
    # at the least of both, the slow-down crosses the scale's whole range (1 to 0) in 11 s; scale_rate 1e-300 was
    # taken, and the playback clock stayed at the speed it had whatever cap was asked for
    scale_rate: float = Field(default=2.0, ge=0.1, description="largest rate of change of the speed scale [1/s]")
    scale_accel: float = Field(default=40.0, ge=0.1, description="[1/s²]")

    @field_validator("box")
    @classmethod
    def _min_below_max(cls, box):
        if box is not None and not all(lo < hi for lo, hi in zip(*box)):
            raise ValueError(f"each minimum must be below its maximum, got {box}")
        if box is not None and max(abs(c) for corner in box for c in corner) > BOX_LIMIT_M:
            raise ValueError(f"{[list(corner) for corner in box]} reaches beyond {BOX_LIMIT_M:g} m, farther than any "
                             "robot cell; the box is in metres, not millimetres or centimetres")
        return box
