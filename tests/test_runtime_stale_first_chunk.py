"""A first chunk whose steps have all passed does not start the run: it plays nothing, and the chunk after it is
the run's first, approached from the measured pose. A stale first chunk started the run (the start-up checks and
the approach were spent on it), and the next one, 0.5 rad from the pose, was played straight through the guard's
limits (limit interventions, no approach)."""

from __future__ import annotations

import numpy as np

from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def _run(tmp_path, first_t: float) -> Run:
    """One 1.5 s time cycle of a replay whose first chunk (at ``first_t`` s) holds the home pose and whose next ones,
    from 0.1 s, hold a pose 0.5 rad away at the base."""
    home = np.array(make_cell("arm-pick-place").read().q, dtype=np.float64)
    away = home + np.array([0.5, 0, 0, 0, 0, 0])
    actions = np.stack([np.tile(home, (25, 1)), np.tile(away, (25, 1)), np.tile(away, (25, 1))])
    np.savez(tmp_path / "mixed.npz", t=np.array([first_t, 0.1, 0.6]), actions=actions, dt=np.float64(0.02))
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{tmp_path / 'mixed.npz'}",
                              "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 1.5}}))
    try:
        run.run_cycles()
    finally:
        run.close()
    return run


def test_a_stale_first_chunk_leaves_the_next_one_to_start_the_run_with_its_approach(tmp_path):
    run = _run(tmp_path, first_t=-5.0)
    kinds = [e.kind for e in run.events]
    assert "chunk_stale" in kinds
    assert "approach_begin" in kinds and kinds.index("chunk_stale") < kinds.index("approach_begin")
    assert "limit_intervention" not in kinds  # the far pose was approached, not played through the limits

