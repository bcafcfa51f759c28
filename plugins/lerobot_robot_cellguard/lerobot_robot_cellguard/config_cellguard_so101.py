"""The config of the ``cellguard_so101`` robot type, registered in LeRobot's robot config registry."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.robots import RobotConfig


@RobotConfig.register_subclass("cellguard_so101")
@dataclass
class CellguardSO101Config(RobotConfig):
    """``max_relative_target`` as on LeRobot's SO follower, in its units (degrees, gripper 0..100).

    ``action_period_s``: simulated time each ``send_action`` advances [s]; the simulated arm moves
    only when commanded, so a loop at F Hz sets 1/F (1 ms for a 1 kHz guard loop, 1/30 for
    ``lerobot-record --dataset.fps=30``). ``units``: the units map file (default: the SO-101's).
    ``faults``: a cellguard scenario file whose ``faults`` act on the simulated world as its
    cycles pass (a shifted fixture, a growing friction); the robot itself knows nothing of them.
    """

    seed: int = 0
    max_relative_target: float | dict[str, float] | None = None
    action_period_s: float = 0.001
    units: str | None = None
    faults: str | None = None
