"""Robot profile: joints, limits, measured parameters (value, unit, when, how), symmetry; kinematics."""

from cellguard.embodiment.kinematics import Kinematics
from cellguard.embodiment.profile import (
    Calibration,
    JointLimits,
    MeasuredParameter,
    Profile,
    SymmetryPair,
    load_profile,
)

__all__ = ["Calibration", "JointLimits", "Kinematics", "MeasuredParameter", "Profile", "SymmetryPair", "load_profile"]
