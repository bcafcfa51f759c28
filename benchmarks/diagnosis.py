"""Diagnosis benchmark: every fault kind at three magnitudes and three seeds, plus fault-free runs.

Prints one JSON document and writes the markdown table pasted into README.md. The diagnosis
sees only cycles and events (never the injected faults); this script alone knows them, to score.

    .venv/bin/python benchmarks/diagnosis.py [--md FILE] [--free-cycles 200] [--hour] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from cellguard.diagnose import diagnose
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

ACCEPTANCE, PRODUCTION, AT = 20, 12, 24  # fault runs: 4 clean production cycles, then 8 with the fault
SEEDS = (0, 1, 2)
DIRECTIONS = ((1.0, 0.0), (0.0, -1.0), (0.7071, 0.7071))  # per seed, for the geometric faults
FRICTION_JOINTS = ("elbow", "shoulder_lift", "wrist_flex")
SERVO_JOINTS = ("shoulder_lift", "elbow", "shoulder_pan")
LEVELS = ("small", "moderate", "large")
EXPECTED = {"fixture_shift": "fixture_shift", "camera_shift": "camera_shift", "tool_slip": "tool_slip",
            "friction_growth": "friction", "servo_gain": "servo", "policy_latency": "policy_latency",
            "policy_nan": "policy_output"}
MAGNITUDES = {"fixture_shift": (1.0, 3.0, 5.0), "camera_shift": (1.0, 3.0, 5.0), "tool_slip": (1.0, 2.0, 3.0),
              "friction_growth": (0.02, 0.05, 0.1), "servo_gain": (0.9, 0.8, 0.6), "policy_latency": (20, 60, 150),
              "policy_nan": (1, 2, 3)}
UNITS = {"fixture_shift": "mm", "camera_shift": "mm", "tool_slip": "mm", "friction_growth": "x nominal/cycle",
         "servo_gain": "x gain", "policy_latency": "ms", "policy_nan": "bad chunks"}


def faults(kind: str, magnitude: float, seed: int) -> list[dict]:
    dx, dy = (magnitude * d for d in DIRECTIONS[seed])
    if kind in ("fixture_shift", "camera_shift", "tool_slip"):
        return [{"kind": kind, "at_cycle": AT, "dx_mm": round(dx, 3), "dy_mm": round(dy, 3)}]
    if kind == "friction_growth":
        return [{"kind": kind, "joint": FRICTION_JOINTS[seed], "from_cycle": AT, "per_cycle": magnitude}]
    if kind == "servo_gain":
        return [{"kind": kind, "joint": SERVO_JOINTS[seed], "factor": magnitude, "at_cycle": AT}]
    if kind == "policy_latency":
        return [{"kind": kind, "at_cycle": AT, "ms": magnitude}]
    return [{"kind": "policy_nan", "at_cycle": AT + i} for i in range(int(magnitude))]


def run(seed: int, production: int, fault_list: list[dict]):
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": seed, "acceptance_cycles": ACCEPTANCE,
                               "production_cycles": production, "faults": fault_list})
    r = Run(scenario)
    for _ in range(scenario.total_cycles):
        r.cycle()
    return r


def score(kind: str, r: Run) -> dict:
    """Detected at the first drift alarm at or after the fault (a rejected chunk is an incident:
    detected in its own cycle); cause from the first finding from the fault on."""
    t0 = time.perf_counter()
    d = diagnose(r.cycles, r.events, {})
    elapsed = time.perf_counter() - t0
    early = [a for a in d.drift.alarms if a.cycle < AT] + [f for f in d.findings if f.cycle < AT - 1]
    after = [f for f in d.findings if f.cycle >= AT - 1]
    alarms = [a.cycle for a in d.drift.alarms if a.cycle >= AT]
    alarms += [f.cycle for f in after if f.cause == "policy_output"]
    first = min(alarms) if alarms else None
    named = after[0].cause if after else None
    return {"detected": first is not None, "delay": (first - AT) if first is not None else None,
            "cause": named, "correct": named == EXPECTED[kind], "false_alarms": len(early),
            "onset": after[0].cycle if after else None, "diagnose_s": elapsed}


def fault_free(seed: int, production: int) -> dict:
    r = run(seed, production, [])
    t0 = time.perf_counter()
    d = diagnose(r.cycles, r.events, {})
    out = {"seed": seed, "production_cycles": production, "drift_alarms": len(d.drift.alarms),
           "findings": [f.cause for f in d.findings], "diagnose_s": time.perf_counter() - t0,
           "max_cusum_over_h": float(max(d.drift.upper.max(), d.drift.lower.max()) / d.drift.threshold),
           "max_mewma_over_limit": float(d.drift.mewma.max() / d.drift.mewma_threshold)}
    print(f"fault-free seed {seed}: {out}", file=sys.stderr, flush=True)
    return out


def _task(task: tuple) -> tuple:
    if task[0] == "free":
        return task, fault_free(task[1], task[2])
    if task[0] == "hour":
        return task, one_hour()
    kind, level, magnitude, seed = task
    result = score(kind, run(seed, PRODUCTION, faults(kind, magnitude, seed)))
    print(f"{kind} {level} seed {seed}: {result}", file=sys.stderr, flush=True)
    return task, result


def one_hour() -> dict:
    """A recorded hour of the arm cell (about 810 cycles), then ``diagnose DIR`` on the record."""
    from cellguard.diagnose.from_record import diagnose_record
    from cellguard.runtime import run_scenario

    cycles = round(3600 / 4.444)
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": ACCEPTANCE,
                               "production_cycles": cycles - ACCEPTANCE,
                               "faults": [{"kind": "fixture_shift", "at_cycle": 600, "dx_mm": 3.0}]})
    with tempfile.TemporaryDirectory() as tmp:
        run_scenario(scenario, Path(tmp))
        t0 = time.perf_counter()
        d = diagnose_record(Path(tmp))
        elapsed = time.perf_counter() - t0
    return {"cycles": len(d.cycles), "diagnose_record_s": round(elapsed, 3),
            "findings": [f.to_dict()["cause"] for f in d.findings], "first_faulted_cycle": d.first_faulted_cycle}


def table(rows: list[dict], free: list[dict]) -> str:
    lines = ["| fault | level | magnitude | detected | cause correct | delay [cycles] median (max) | false alarms |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        delays = [d for d in r["delays"] if d is not None]
        delay = f"{np.median(delays):.0f} ({max(delays)})" if delays else "-"
        lines.append(f"| {r['kind']} | {r['level']} | {r['magnitude']:g} {UNITS[r['kind']]} | {r['detected']}/{r['n']} "
                     f"| {r['correct']}/{r['n']} | {delay} | {r['false_alarms']} |")
    total = sum(f["production_cycles"] for f in free)
    alarms = sum(f["drift_alarms"] + len(f["findings"]) for f in free)
    lines.append(f"| none (fault-free) | - | {len(free)} runs x {free[0]['production_cycles']} production cycles | "
                 f"- | - | - | {alarms} in {total} cycles |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--md", type=Path, default=None, help="write the markdown table here")
    ap.add_argument("--free-cycles", type=int, default=200)
    ap.add_argument("--kinds", nargs="*", default=list(EXPECTED))
    ap.add_argument("--hour", action="store_true", help="also time diagnose on a recorded one-hour run")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    tasks = [("hour",)] if args.hour else []
    tasks += [("free", seed, args.free_cycles) for seed in SEEDS]
    tasks += [(kind, level, magnitude, seed) for kind in args.kinds
              for level, magnitude in zip(LEVELS, MAGNITUDES[kind]) for seed in SEEDS]
    with Pool(args.workers) as pool:
        done = dict(pool.map(_task, tasks, chunksize=1))
    rows = []
    for kind in args.kinds:
        for level, magnitude in zip(LEVELS, MAGNITUDES[kind]):
            results = [done[(kind, level, magnitude, seed)] for seed in SEEDS]
            rows.append({"kind": kind, "level": level, "magnitude": magnitude, "n": len(results),
                         "detected": sum(r["detected"] for r in results),
                         "correct": sum(r["correct"] for r in results),
                         "delays": [r["delay"] for r in results], "causes": [r["cause"] for r in results],
                         "false_alarms": sum(r["false_alarms"] for r in results)})
    free = [done[("free", seed, args.free_cycles)] for seed in SEEDS]
    graded = [r for r in rows if r["level"] != "small"]
    summary = {
        "cause_accuracy_moderate_large": sum(r["correct"] for r in graded) / max(sum(r["n"] for r in graded), 1),
        "detection_rate_all": sum(r["detected"] for r in rows) / max(sum(r["n"] for r in rows), 1),
        "false_alarms_fault_free": sum(f["drift_alarms"] + len(f["findings"]) for f in free),
        "false_alarms_before_fault": sum(r["false_alarms"] for r in rows),
        "fixture_3mm_max_delay": max((d for r in rows if r["kind"] == "fixture_shift" and r["magnitude"] == 3.0
                                      for d in r["delays"] if d is not None), default=None),
    }
    out = {"rows": rows, "fault_free": free, "summary": summary}
    if args.hour:
        out["one_hour"] = done[("hour",)]
    md = table(rows, free)
    if args.md:
        args.md.write_text(md + "\n")
    print(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
