"""Cycles, baseline, drift, last-good versus faulted, asymmetry, probable cause."""

from cellguard.diagnose.asymmetry import Asymmetry, mirrored_asymmetry
from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cause import CAUSES, Finding
from cellguard.diagnose.cycles import Cycle, as_cycles
from cellguard.diagnose.diagnosis import Diagnosis, diagnose
from cellguard.diagnose.drift import DriftAlarm, DriftConfig, detect_drift

__all__ = ["CAUSES", "Asymmetry", "Baseline", "Cycle", "Diagnosis", "DriftAlarm", "DriftConfig", "Finding",
           "as_cycles", "detect_drift", "diagnose", "mirrored_asymmetry"]
