"""LeRobot robot type ``cellguard_so101``: cellguard's simulated SO-101 cell behind LeRobot's ``Robot`` API.

Importing this package registers the config with ``RobotConfig.register_subclass``; LeRobot's
scripts import it through ``register_third_party_plugins`` and build the robot with
``make_robot_from_config`` (which finds ``CellguardSO101`` here by its config's class name).
"""

from lerobot_robot_cellguard.cellguard_so101 import CellguardSO101
from lerobot_robot_cellguard.config_cellguard_so101 import CellguardSO101Config

__all__ = ["CellguardSO101", "CellguardSO101Config"]
