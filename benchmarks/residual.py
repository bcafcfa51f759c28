"""Residual monitor benchmark: false alarms over fault-free cycles, and what a drift looks like.

Per cell: ``--cycles`` fault-free cycles (the first ten are the monitor's baseline) with the count of
alarms and the largest CUSUM statistic (1.0 is the threshold), with the monitor's design (threshold, cap,
the set's false-alarm rate and the chance of any false alarm over this many windows that it implies) and
whether the run reached every cycle (timeouts, an early stop); then, in fresh runs, +30 % dry friction
on one joint and (the arm) a heavier payload at the tool from cycle ``AT``: the windows until the first
alarm, and which joint and parameter it names. The model is the nominal one (the simulated cells'
physics is nominal, so nominal is calibrated here). Prints one JSON document. A 300-cycle run takes
minutes: run it in the background (``nohup ... > out.json &``), ``--progress`` shows it as it goes.

    .venv/bin/python benchmarks/residual.py [--cycles 300] [--cells arm-pick-place,quadruped-turns]
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np

import math
import time

from cellguard.calibrate.residual import BASELINE_WINDOWS, FORECAST, K, ResidualMonitor, watch
from cellguard.runtime.loop import Run
from cellguard.scenario import Scenario

AT = BASELINE_WINDOWS + 2  # the cycle from which a drift is injected
FRICTION = {"arm-pick-place": "elbow", "quadruped-turns": "fl_knee"}
PAYLOAD_KG = 0.1


def monitored(cell: str, cycles: int, change=None, progress=None, run_info: dict | None = None) -> list[dict]:
    """Each cycle's residual window of a run of ``cycles``; ``change(run)`` is applied at cycle ``AT``;
    ``progress``: a file that gets one JSON line per window as it ends (a long run can be read while it runs);
    ``run_info`` gets the monitor's design and how the run went (timeouts, an early stop, wall time)."""
    run = Run(Scenario(cell=cell, acceptance_cycles=cycles, production_cycles=0))
    monitor = ResidualMonitor(run.cell)
    watch(run, monitor)
    windows, timed_out, t0 = [], 0, time.perf_counter()
    try:
        for c in range(cycles):
            if change is not None and c == AT:
                change(run)
            outcome = run.cycle()
            timed_out += bool(outcome.get("timed_out"))
            windows.append(outcome["residual"])
            if progress is not None:
                w = windows[-1]
                progress.write(json.dumps({"cell": cell, "window": w["window"], "alarms": w["alarms"],
                                           "max_cusum": max(map(max, w["cusum"])) if "cusum" in w else None}) + "\n")
                progress.flush()
    finally:
        run.close()
    if run_info is not None:
        run_info.update({"threshold_h": monitor.threshold, "score_cap": monitor.cap, "k": K, "forecast_weight": FORECAST,
                         "cusums": 2 * len(monitor.model.joints) * len(monitor.signatures),
                         "set_arl_windows": monitor.set_arl, "timed_out_cycles": timed_out, "stopped": run.stopped,
                         "wall_s": round(time.perf_counter() - t0, 1)})
    return windows


def first_alarm(windows: list[dict]) -> dict | None:
    for w in windows[AT:]:
        if w["alarms"]:
            return {"windows_after_change": w["window"] - AT + 1, "alarms": w["alarms"]}
    return None


def add_payload(run) -> None:
    m = run.cell.model
    m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")] += PAYLOAD_KG


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cycles", type=int, default=300)
    parser.add_argument("--cells", default=",".join(FRICTION))
    parser.add_argument("--progress", type=argparse.FileType("w"), default=None,
                        help="write one JSON line per fault-free window here as it ends")
    args = parser.parse_args()
    out = []
    for cell in args.cells.split(","):
        info: dict = {}
        quiet = monitored(cell, args.cycles, progress=args.progress, run_info=info)
        stats = [max(map(max, w["cusum"])) for w in quiet if "cusum" in w]
        joint = FRICTION[cell]
        friction = monitored(cell, AT + 6, lambda run, j=joint: run.cell.set_friction_scale(j, 1.3))
        design = {**info, "p_any_false_alarm_over_run": 1.0 - math.exp(-len(stats) / info["set_arl_windows"])}
        row = {"cell": cell, "fault_free": {"cycles": len(quiet), "monitored_windows": len(stats),
                                            "alarms": sum(len(w["alarms"]) for w in quiet),
                                            "max_cusum_over_threshold": float(np.max(stats)) if stats else None,
                                            "design": design},
               "friction_x1.3": {"joint": joint, "from_window": AT, "first_alarm": first_alarm(friction)}}
        if cell == "arm-pick-place":
            payload = monitored(cell, AT + 6, add_payload)
            row[f"payload_+{PAYLOAD_KG}kg"] = {"from_window": AT, "first_alarm": first_alarm(payload)}
        out.append(row)
    print(json.dumps({"cells": out}, indent=1))


if __name__ == "__main__":
    main()
