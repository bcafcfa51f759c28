"""Building the guard layer for a cell from its ``guard:`` settings (``GuardConfig``)."""

from __future__ import annotations

import numpy as np

from cellguard.control.config import GuardConfig
from cellguard.control.guard import Guard
from cellguard.control.reach import MARGIN
from cellguard.errors import ConfigError

REACH_SAMPLES = 256  # poses sampled over the joint ranges to find the reach (about 2 ms on the arm)
REACH_WALLS = 2  # a wall may lie this many reaches beyond where the tool gets (a fence drawn round the cell)


def build_guard(cell, settings: GuardConfig | None = None, q0: np.ndarray | None = None) -> Guard:
    """The guard layer for ``cell``, with its kinematics and workspace box if it has them, at rest at ``q0``
    (default: the measured pose).

    The tool model is the cell's ``kinematics`` (an ``embodiment.Kinematics`` of its nominal MJCF)
    where it offers one, else its ``tool_point``. The box is the scenario's if it sets one, else the
    cell's; it is checked only where there is a tool model, and a box of the scenario's must not reach far beyond
    where the tool gets (``check_box_reach``).
    """
    config = settings or GuardConfig()
    kinematics = getattr(cell, "kinematics", None)
    tool = kinematics.tool_point if kinematics is not None else getattr(cell, "tool_point", None)
    unchecked = [key for key in ("box", "tool_speed_max") if tool is None and getattr(config, key) is not None]
    if unchecked:  # accepted, recorded as in force and never checked
        raise ConfigError(f"guard.{unchecked[0]}: cell {cell.profile.robot} has no tool model to check it against; "
                          "remove it")
    if tool is not None and config.box is not None:
        check_box_reach(config.box, cell, tool)
    box = config.box if config.box is not None else getattr(cell, "workspace_box", None)
    config = config.model_copy(update={"box": box if tool is not None else None})
    check_home(cell, config, tool)
    return Guard(cell.profile, cell.read().q if q0 is None else q0, cell.dt_ns, config, tool=tool)


def check_home(cell, config: GuardConfig, tool) -> None:
    """Refuse settings that leave the cell's home pose (``q_home``, where each run starts and retreats to) outside
    the soft limits or its tool point outside the box: the approach stopped short at a soft limit and the retreat
    went past it (cycles of 12 s for 4.4 with ``soft_margin: 0.2`` on the arm), or the retreat home was refused at
    the end of a whole run."""
    home = getattr(cell, "q_home", None)
    if home is None:
        return
    profile, home = cell.profile, np.asarray(home, dtype=np.float64)
    j = profile.first_outside(home, slack=-config.soft_margin)  # widened by minus the margin: the soft limits
    if j is not None:
        joint, (lo, hi) = profile.joints[j], (limit[j] for limit in profile.soft_limits(config.soft_margin))
        unit = "rad" if joint.kind == "hinge" else "m"
        raise ConfigError(f"guard.soft_margin: {config.soft_margin:g} puts the soft limits of {joint.name} at "
                          f"[{lo:.4g}, {hi:.4g}] {unit}, leaving out its home pose {home[j]:.4g} {unit}; lower it")
    if tool is not None and config.box is not None:
        tip = np.asarray(tool(home), dtype=np.float64)
        if not ((np.asarray(config.box[0]) <= tip) & (tip <= np.asarray(config.box[1]))).all():
            raise ConfigError(f"guard.box: {[list(map(float, corner)) for corner in config.box]} m leaves out the "
                              f"home pose's tool point {np.round(tip, 3).tolist()} m")


def check_box_reach(box, cell, tool) -> None:
    """Refuse a box with a wall more than ``REACH_WALLS`` reaches beyond the farthest the tool gets along that axis: a
    wall the tool never comes near guards nothing, and the workspace check was off with no word. Such a box is mostly
    one written in millimetres, centimetres or decimetres and read as metres (``[[-45, -45, 0.5], [45, 45, 55]]``,
    centimetres, on a 0.69 m arm); ten times the tool's distance from the origin, the bound before, took a box in
    decimetres, and a 10 m box on a decimetre-scale arm. Where the tool gets: ``REACH_SAMPLES`` poses over the joint
    ranges and the cell's own box, widened by ``reach.MARGIN`` (no sample lands on the farthest pose); its reach: half
    the widest span of those. A fence drawn round the cell in metres (1.5 m round the 0.69 m arm, 1 m round the
    SO-101) passes."""
    profile = cell.profile
    poses = np.random.default_rng(0).uniform(profile.q_min, profile.q_max, (REACH_SAMPLES, profile.dof))
    points = np.array([tool(q) for q in poses] + list(getattr(cell, "workspace_box", None) or ()), dtype=np.float64)
    lo, hi = points.min(axis=0), points.max(axis=0)
    widen = (MARGIN - 1) * (hi - lo) / 2
    lo, hi = lo - widen, hi + widen
    reach = float((hi - lo).max()) / 2
    walls = np.asarray(box, dtype=np.float64)
    beyond = np.concatenate([lo - walls[0], walls[1] - hi])  # how far each wall lies out from where the tool gets
    worst = int(np.argmax(beyond))
    if beyond[worst] <= REACH_WALLS * reach:
        return
    axis, side = "xyz"[worst % 3], ("down", "up")[worst // 3]
    raise ConfigError(f"guard.box: {walls.tolist()} m: {axis} {side} to {walls[worst // 3][worst % 3]:g} m lies "
                      f"{beyond[worst]:.2f} m beyond where the tool of {profile.robot} gets ({axis} from "
                      f"{lo[worst % 3]:.2f} to {hi[worst % 3]:.2f} m), over {REACH_WALLS} times its reach of "
                      f"{reach:.2f} m: a wall it never comes near guards nothing (a box in millimetres, centimetres "
                      "or decimetres read as metres?)")
