"""A geometry finding says "current unchanged" only from cycles whose currents were watched: beside a 4 mm camera
shift the grasps fail, the cycles carry another load than the acceptance and their currents go unwatched, so a servo
fault that came with it is not seen (the arm cell, seed 7, shoulder_lift gain x0.85: the camera finding said "current
unchanged" from the one cycle of ten that grasped)."""

from __future__ import annotations

import numpy as np
import pytest
from test_diagnosis_path_allowance import GEOMETRY, JOINTS

from cellguard.diagnose import diagnose
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

CAMERA_4MM = {"part_seen_x_mm": -4.0, "fixture_seen_x_mm": -4.0, "grasp_tcp_x_mm": -3.0, "grasp_offset_x_mm": 3.0}
SLIP_3MM = {"grasp_offset_x_mm": 3.0}
AT, N = 25, 45


def _arm(grasped: set[int], n: int = N, shift: dict = CAMERA_4MM, hits: set[int] | None = None) -> list[dict]:
    """An arm whose geometry moves by ``shift`` [mm] on the cycles ``hits`` (default: from ``AT`` on), its joints
    unchanged; from ``AT`` on only the cycles ``grasped`` hold a part (the others carry another load)."""
    rng = np.random.default_rng(0)
    rows = []
    for i in range(n):
        base = {k: v for features in JOINTS.values() for k, v in features.items()} | GEOMETRY
        f = {k: v + (0.01 if k.endswith("_mm") else 2e-3 * v) * rng.standard_normal() for k, v in base.items()}
        f["grasped"] = 1.0 if i < AT or i in grasped else 0.0
        if i >= AT if hits is None else i in hits:
            for k, d in shift.items():
                f[k] += d
        rows.append({"cycle": i, "phase": "acceptance" if i < 15 else "production", "success": f["grasped"] == 1.0,
                     "features": f})
    return rows


def _only(rows: list[dict], cause: str, cycle: int) -> str:
    """The evidence of the one finding ``rows`` give, which must be ``cause`` from ``cycle``."""
    d = diagnose(rows, [], {})
    assert [(f.cause, f.cycle) for f in d.findings] == [(cause, cycle)], [f.to_dict() for f in d.findings]
    return " ".join(d.findings[0].evidence)


@pytest.mark.parametrize("grasped", [(), (30,), (27, 31, 36, 40)])
def test_no_current_unchanged_from_too_few_watched_cycles(grasped):
    """None, one or four of the twenty cycles from the shift on watched: the finding says the drives went unwatched
    and on how many cycles they were, never "current unchanged"."""
    words = _only(_arm(set(grasped)), "camera_shift", AT)
    assert "current unchanged" not in words, words
    assert (f"drives not watched: joint currents watched on {len(grasped)} of its 20 cycles, too few to rule out a "
            "drive fault") in words, words


@pytest.mark.parametrize("grasped, n", [(set(range(AT, 30)) | {33, 38}, N), (set(range(AT, 28)), 28)])
def test_current_unchanged_from_enough_watched_cycles(grasped, n):
    """Seven of twenty cycles watched, or every cycle of a record that ends three cycles after the shift: the
    currents were read where they could be, and they did not change."""
    words = _only(_arm(grasped, n), "camera_shift", AT)
    assert "current unchanged" in words and "drives not watched" not in words, words


def test_an_intermittent_slip_says_nothing_of_the_drives_from_its_hit_cycles():
    """A tool that slips on six cycles, two of which still held the part: the drives are watched on the cycles
    between the hits, so the finding neither says "current unchanged" from those two nor that the drives went
    unwatched."""
    hits = {27, 30, 34, 35, 39, 43}
    words = _only(_arm(set(range(AT, N)) - hits | {30, 39}, shift=SLIP_3MM, hits=hits), "tool_slip", 27)
    assert "intermittent: 6 of" in words and "current unchanged" not in words and "drives not" not in words, words


def test_on_the_arm_cell_a_4mm_camera_shift_with_a_servo_fault_does_not_say_current_unchanged():
    """The arm cell, seed 7: a 4 mm camera shift and shoulder_lift's gain x0.85 at the same cycle. The grasps fail
    from the shift on (one of eight holds the part), so the drives go unwatched and the servo fault is not named;
    the camera finding says so instead of "current unchanged"."""
    faults = [{"kind": "camera_shift", "at_cycle": 10, "dx_mm": 4.0},
              {"kind": "servo_gain", "joint": "shoulder_lift", "factor": 0.85, "at_cycle": 10}]
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 6, "production_cycles": 12,
                              "faults": faults}))
    for _ in range(18):
        run.cycle()
    d = diagnose(run.cycles, run.events, {})
    camera = next(f for f in d.findings if f.cause == "camera_shift")
    watched = 18 - 10 - len([c for c in d.unwatched if c >= 10])
    words = " ".join(camera.evidence)
    assert watched < 5 and "current unchanged" not in words, (watched, words)
    assert f"drives not watched: joint currents watched on {watched} of its 8 cycles, too few to rule out" in words, \
        words
