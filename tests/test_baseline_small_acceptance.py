"""A baseline from a handful of acceptance cycles must not read the noise low: the drift and
intermittent monitors count in its scales, so a scale read low names faults on a healthy cell."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.diagnose import diagnose
from cellguard.diagnose.baseline import SIGMA_LEVEL, robust_sigma

NAMES = ("part_seen_x_mm", "part_seen_y_mm", "grasp_tcp_x_mm", "grasp_tcp_y_mm", "current_rms.elbow",
         "tracking_rms.elbow", "current_rms.wrist_flex")
CENTRE = np.array([100.0, 200.0, 300.0, 400.0, 0.41, 0.0133, 0.3])
SIGMA = np.array([0.25, 0.25, 0.25, 0.25, 0.004, 2e-4, 0.004])  # part placement noise well above the floors


def test_five_cycles_with_one_far_one_keep_its_spread():
    """Five acceptance cycles of a part placed with 0.25 mm of noise (a fault-free arm, seed 8): the
    one far reading is honest; winsorised at 3 MAD-sigmas it was clipped and the scale read 0.053 mm."""
    y = np.array([100.102, 100.172, 100.086, 100.093, 99.79])[:, None]
    assert robust_sigma(y)[0] >= 0.251  # the spread of that feature over all 45 cycles of the run


@pytest.mark.parametrize("n", [5, 6, 8, 12])
def test_a_scale_from_few_cycles_seldom_reads_below_sigma(n):
    x = np.random.default_rng(n).standard_normal((n, 4000))
    below = float(np.mean(robust_sigma(x) < 1.0))
    assert below <= SIGMA_LEVEL + 0.01


def _rows(n: int, rng: np.random.Generator, start: int, phase: str) -> list[dict]:
    out = []
    for i in range(n):
        f = dict(zip(NAMES, (CENTRE + SIGMA * rng.standard_normal(len(NAMES))).tolist()), grasped=1.0)
        out.append({"cycle": start + i, "phase": phase, "success": True, "features": f})
    return out


@pytest.mark.parametrize("n", [5, 6, 8])
def test_a_healthy_run_after_a_small_acceptance_names_nothing(n):
    for seed in range(12):
        rng = np.random.default_rng(seed)
        d = diagnose(_rows(n, rng, 0, "acceptance") + _rows(40, rng, n, "production"), [], {})
        assert d.findings == () and d.drift.alarms == (), (seed, [(f.cause, f.cycle) for f in d.findings])
