"""Robot profile: joints, limits, measured parameters (value, unit, when, how), symmetry."""

from cellguard.embodiment.profile import (
    JointLimits,
    MeasuredParameter,
    Profile,
    SymmetryPair,
    load_profile,
)

__all__ = ["JointLimits", "MeasuredParameter", "Profile", "SymmetryPair", "load_profile"]
