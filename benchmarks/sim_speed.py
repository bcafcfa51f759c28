"""Simulated seconds per wall second for every registered cell through the full tick path.

Prints one JSON document: {cell: {"cycles", "sim_s", "wall_s", "sim_s_per_wall_s", "us_per_tick"}}.
"""

from __future__ import annotations

import json
import sys
import time

from cellguard.robot.registry import CELLS
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def measure(cell: str, cycles: int) -> dict:
    run = Run(parse_scenario({"cell": cell, "seed": 1, "acceptance_cycles": cycles, "production_cycles": 0}))
    t0_sim, t0 = run.cell.t_ns, time.perf_counter()
    for _ in range(cycles):
        run.cycle()
    wall = time.perf_counter() - t0
    sim = (run.cell.t_ns - t0_sim) * 1e-9
    return {"cycles": cycles, "sim_s": round(sim, 3), "wall_s": round(wall, 3),
            "sim_s_per_wall_s": round(sim / wall, 2), "us_per_tick": round(wall / (sim * 1e3) * 1e6, 2)}


if __name__ == "__main__":
    cycles = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    print(json.dumps({name: measure(name, cycles) for name in CELLS}, indent=1))
