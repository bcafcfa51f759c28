"""The ``guard:`` section of a scenario file, and building the executor and envelope for a cell."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from cellguard.control.envelope import EnvelopeConfig
from cellguard.control.guard import Guard


class GuardSettings(BaseModel):
    """Envelope settings a scenario may change; the joint limits come from the embodiment profile."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    watchdog_s: float = Field(default=0.3, gt=0.0, le=10.0, description="policy silence before a stop [s]")
    watchdog_category: int = Field(default=2, ge=0, le=2, description="IEC 60204-1 stop category on silence")
    uncertainty_threshold: float | None = Field(default=None, ge=0.0)
    uncertainty_action: Literal["reduce", "hold"] = "reduce"
    tool_speed_max: float | None = Field(default=None, gt=0.0, le=10.0, description="[m/s]")
    reduced_speed: float = Field(default=0.25, gt=0.0, le=0.25, description="[m/s], ISO 10218-1: at most 0.25")
    blend_s: float = Field(default=0.2, gt=0.0, le=1.0, description="chunk stitching blend [s]")
    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = Field(
        default=None, description="tool-point box [[xmin, ymin, zmin], [xmax, ymax, zmax]] [m]; default: the cell's")

    @field_validator("box")
    @classmethod
    def _min_below_max(cls, box):
        if box is not None and not all(lo < hi for lo, hi in zip(*box)):
            raise ValueError(f"each minimum must be below its maximum, got {box}")
        return box


def build_guard(cell, settings: GuardSettings | None = None) -> Guard:
    """The guard layer for ``cell``, with its forward kinematics and workspace box if it has them."""
    s = settings or GuardSettings()
    tool = getattr(cell, "tool_point", None)
    box = s.box if s.box is not None else getattr(cell, "workspace_box", None)
    config = EnvelopeConfig(watchdog_s=s.watchdog_s, watchdog_category=s.watchdog_category,
                            uncertainty_threshold=s.uncertainty_threshold, uncertainty_action=s.uncertainty_action,
                            tool_speed_max=s.tool_speed_max, reduced_speed=s.reduced_speed,
                            box=box if tool is not None else None)
    return Guard(cell.profile, cell.read().q, cell.dt_ns, config, blend_ns=round(s.blend_s * 1e9), tool=tool)
