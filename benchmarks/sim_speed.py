"""Simulated seconds per wall second for every registered cell through the full tick path.

The machine is shared and its speed varies, so each cell's cost per tick is also given as a
ratio to one ``mj_step`` of the same cell measured in the same run (CPU time, best of 5 x 1000
steps from the cell's start pose, before and after the loop; the loop's own steps see contacts
and cost more). Prints one JSON document: {cell: {"cycles", "sim_s", "wall_s", "sim_s_per_wall_s",
"us_per_tick", "cpu_us_per_tick", "mj_step_us", "tick_in_mj_steps"}}.

    python benchmarks/sim_speed.py [CYCLES]     # cycles per cell, default 5
"""

from __future__ import annotations

import argparse
import json
import time

import mujoco

from cellguard.robot.registry import CELLS, make_cell
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario


def mj_step_us(cell: str) -> float:
    """CPU time of one mj_step of a fresh ``cell`` [us], best of 5 x 1000."""
    c = make_cell(cell, seed=1)
    best = float("inf")
    for _ in range(5):
        t = time.process_time()
        for _ in range(1000):
            mujoco.mj_step(c.model, c.data)
        best = min(best, (time.process_time() - t) * 1e3)
    return best


def measure(cell: str, cycles: int) -> dict:
    step_before = mj_step_us(cell)
    run = Run(parse_scenario({"cell": cell, "seed": 1, "acceptance_cycles": cycles, "production_cycles": 0}))
    t0_sim, t0, c0 = run.cell.t_ns, time.perf_counter(), time.process_time()
    for _ in range(cycles):
        run.cycle()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    step = min(step_before, mj_step_us(cell))
    sim = (run.cell.t_ns - t0_sim) * 1e-9
    ticks = (run.cell.t_ns - t0_sim) / run.cell.dt_ns
    return {"cycles": cycles, "sim_s": round(sim, 3), "wall_s": round(wall, 3),
            "sim_s_per_wall_s": round(sim / wall, 2), "us_per_tick": round(wall / ticks * 1e6, 2),
            "cpu_us_per_tick": round(cpu / ticks * 1e6, 2), "mj_step_us": round(step, 2),
            "tick_in_mj_steps": round(cpu / ticks * 1e6 / step, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cycles", nargs="?", type=int, default=5, help="acceptance cycles per cell (default 5)")
    args = ap.parse_args()
    if args.cycles < 1:  # no tick to divide by
        ap.error(f"cycles: at least 1, got {args.cycles}")
    print(json.dumps({name: measure(name, args.cycles) for name in CELLS}, indent=1))


if __name__ == "__main__":
    main()
