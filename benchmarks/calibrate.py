"""Calibration benchmark: hidden physics on the arm cell, recovered from its own excitation record.

The simulated cell's physics is changed away from the nominal MJCF (friction x1.5 on two joints,
armature x0.7, +50 g payload at the tool, 4 ms command delay); only this script knows it. The
fit starts from the nominal model and sees only the record. Prints one JSON document: the table
(true, nominal, identified, 95 % interval, inside), identify's wall time as a multiple of one
``mj_step`` of the same cell measured in the same run, and what production cycles alone identify.

    .venv/bin/python benchmarks/calibrate.py [--seconds 60] [--production-cycles 3]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import mujoco

from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.calibrate.identify import identify, load_segments, model_params
from cellguard.record.writer import RecordConfig
from cellguard.robot.physics import Physics
from cellguard.robot.registry import make_cell
from cellguard.runtime.loop import Run, run_scenario
from cellguard.scenario import Scenario

ARM = "arm-pick-place"
TRUTH = Physics(friction={"shoulder_lift": 1.5, "elbow": 1.5}, armature=0.7, payload_kg=0.05, delay_s=0.004)


def true_value(e: dict) -> float:
    """What the hidden physics makes parameter ``e`` (a row of identify's estimates)."""
    p, joint = e["parameter"], e["joint"]
    if p == "friction":
        return e["nominal"] * TRUTH.friction.get(joint, 1.0)
    if p == "armature":
        return e["nominal"] * TRUTH.armature
    return {"payload": TRUTH.payload_kg, "delay": TRUTH.delay_s}.get(p, e["nominal"])


def table(result: dict) -> list[dict]:
    rows = []
    for e in result["estimates"]:
        truth = true_value(e)
        row = {"parameter": e["parameter"], "joint": e["joint"], "unit": e["unit"], "true": truth,
               "nominal": e["nominal"], "identified": e["value"], "interval": e["interval"]}
        if e["interval"] is not None:
            row["inside"] = e["interval"][0] <= truth <= e["interval"][1]
            row["error_rel"] = abs(e["value"] - truth) / abs(truth) if truth else None
        else:
            row["note"] = e["note"]
        rows.append(row)
    return rows


def mj_step_s(cell, n: int = 5000) -> float:
    """Wall time of one ``mj_step`` of ``cell``'s model [s], the median of five batches."""
    data = mujoco.MjData(cell.model)
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n // 5):
            mujoco.mj_step(cell.model, data)
        times.append((time.perf_counter() - t0) / (n // 5))
    return sorted(times)[2]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--production-cycles", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "excite"
        excite(excitation_scenario(ARM, args.seconds), out, physics=TRUTH)
        cell = make_cell(ARM)
        step = mj_step_s(cell)
        t0 = time.perf_counter()
        result = identify(load_segments([out], cell), cell, model_params(cell))
        wall = time.perf_counter() - t0
        rows = table(result)
        production = None
        if args.production_cycles:
            scenario = Scenario(cell=ARM, acceptance_cycles=args.production_cycles, production_cycles=0)
            run = Run(scenario)
            TRUTH.apply(run.cell)
            run_scenario(scenario, Path(tmp) / "production", run=run,
                         record=RecordConfig(decimated_hz=1e9 / run.cell.dt_ns))
            prod = identify(load_segments([Path(tmp) / "production"], cell), cell, model_params(cell))
            production = {"cycles": args.production_cycles, "table": table(prod)}
    identified = [r for r in rows if r["interval"] is not None]
    print(json.dumps({
        "cell": ARM, "excitation_s": args.seconds, "samples": result["samples"],
        "truth": {"friction": TRUTH.friction, "armature_factor": TRUTH.armature, "payload_kg": TRUTH.payload_kg,
                  "delay_s": TRUTH.delay_s},
        "table": rows,
        "inside_interval": f"{sum(r['inside'] for r in identified)}/{len(identified)}",
        "identify_wall_over_mj_step": wall / step,
        "identify_wall_over_excitation_steps": wall / (step * result["samples"]),
        "production_only": production,
    }, indent=1))


if __name__ == "__main__":
    main()
