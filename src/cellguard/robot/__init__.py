"""Robot protocol, MuJoCo cells, and fault injection for simulation."""

from cellguard.robot.protocol import Robot, SimCell
from cellguard.robot.registry import CELLS, make_cell
from cellguard.robot.state import Observation, State

__all__ = ["CELLS", "Observation", "Robot", "SimCell", "State", "make_cell"]
