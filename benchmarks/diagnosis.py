"""Diagnosis benchmark: every fault kind at three magnitudes and three seeds, plus fault-free runs,
and the cases of issue 16 (small faults, process changes, intermittent faults, the quadruped).

Prints one JSON document and writes the markdown table pasted into README.md. The diagnosis
sees only cycles and events (never the injected faults, nor an undeclared process change); this
script alone knows them, to score. Seeds and joints of the issue-16 cases are held out from the
tests (seeds 10 on; joints rotate over the arm's four main axes).

    .venv/bin/python benchmarks/diagnosis.py [--md FILE] [--free-cycles 300] [--hour] [--workers 2]
        [--cases power payload warmup intermittent quadruped arl] [--seeds 9] [--kinds ...] [--runs DIR]

``--runs DIR`` keeps every simulated run (its cycles and events) and reuses it: a changed diagnosis
is re-scored without simulating again. Delete DIR when the cells or the cycle features change.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from multiprocessing import Pool
from pathlib import Path

import mujoco
import numpy as np

from cellguard.diagnose import diagnose
from cellguard.diagnose.baseline import Baseline, MotionStats
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.drift import DriftConfig, _siegmund_arl, detect_drift, siegmund_threshold
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


@dataclass(frozen=True)
class Simulated:
    """What the diagnosis of one simulated run reads: its cycles, events, the context a record of it
    would carry (its declared process changes) and the cell's symmetry map."""

    cycles: list
    events: list
    context: dict
    symmetry: tuple


RUNS: Path | None = None  # --runs DIR: simulated runs kept here and reused (a run is a pure function of its scenario)


def run(seed: int, production: int, fault_list: list[dict], process: list[dict] | None = None,
        cell: str = "arm-pick-place", acceptance: int = ACCEPTANCE) -> Simulated:
    raw = {"cell": cell, "seed": seed, "acceptance_cycles": acceptance, "production_cycles": production,
           "faults": fault_list, "process_changes": process or []}
    kept = RUNS / f"{hashlib.sha256(json.dumps(raw, sort_keys=True).encode()).hexdigest()[:16]}.pkl" if RUNS else None
    if kept is not None and kept.exists():
        return pickle.loads(kept.read_bytes())
    scenario = parse_scenario(raw)
    r = Run(scenario)
    for _ in range(scenario.total_cycles):
        r.cycle()
    out = Simulated(list(r.cycles), list(r.events), {"process": scenario.declared_process(scenario.total_cycles)},
                    tuple(r.cell.profile.symmetry))
    if kept is not None:
        tmp = kept.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(out))
        tmp.replace(kept)
    return out


def _diagnose(r: Simulated, **kw):
    """Diagnose a run in memory with the context a record of it would carry."""
    return diagnose(r.cycles, r.events, r.context, **kw)


# -- issue 16 cases ------------------------------------------------------------------------
POWER_JOINTS = ("shoulder_lift", "elbow", "wrist_flex", "shoulder_pan")
WITHIN = 15  # [cycles] a small fault must be detected and named this soon


def power_case(kind: str, seed: int) -> dict:
    """10 % servo gain loss or friction growing 0.02 per cycle on a held-out joint: detected and named
    within WITHIN cycles?"""
    joint = POWER_JOINTS[seed % len(POWER_JOINTS)]
    fault = ({"kind": "servo_gain", "joint": joint, "factor": 0.9, "at_cycle": AT} if kind == "servo" else
             {"kind": "friction_growth", "joint": joint, "from_cycle": AT, "per_cycle": 0.02})
    d = _diagnose(run(seed, AT - ACCEPTANCE + WITHIN, [fault]))
    named = [f for f in d.findings if f.cycle >= AT - 1 and f.cause == kind and joint in f.joints]
    alarms = [a.cycle for a in d.drift.alarms if a.cycle >= AT]
    early = [a for a in d.drift.alarms if a.cycle < AT] + [f for f in d.findings if f.cycle < AT - 1]
    first = min(alarms) if alarms else None
    return {"kind": kind, "seed": seed, "joint": joint, "detected": first is not None,
            "delay": None if first is None else first - AT, "named": bool(named),
            "causes": [(f.cause, list(f.joints)) for f in d.findings], "false_alarms": len(early)}


def payload_case(declared: bool, seed: int) -> dict:
    """A 40 g heavier product variant from cycle AT, declared in the record or not."""
    r = run(seed, AT - ACCEPTANCE + 12, [], [{"kind": "payload", "at_cycle": AT, "grams": 40.0}])
    if not declared:  # the same physics; the line did not declare it, so its record does not carry it
        r = replace(r, context={"process": []})
    d = _diagnose(r)
    causes = [f.cause for f in d.findings]
    ok = not causes if declared else ("load_change" in causes and not {"friction", "servo"} & set(causes))
    return {"declared": declared, "seed": seed, "causes": causes, "ok": ok,
            "alarms": [a.signal for a in d.drift.alarms][:6], "process": [n.text for n in d.process]}


def warmup_case(seed: int) -> dict:
    """A restart after 2 h idle at cycle AT (friction x1.5 decaying over 4 cycles), declared."""
    change = {"kind": "warmup", "at_cycle": AT, "idle_min": 120, "friction": 0.5, "cycles": 4}
    d = _diagnose(run(seed, AT - ACCEPTANCE + 12, [], [change]))
    return {"seed": seed, "alarms": [a.signal for a in d.drift.alarms], "causes": [f.cause for f in d.findings],
            "ok": not d.drift.alarms and not d.findings, "process": [n.text for n in d.process]}


INTERMITTENT_CYCLES = 100  # [cycles] watched after the fault: 1 in 5 over 40 cycles is 8 +- 2.5 hits, a
# realised rate of 0.2 +- 0.063; over 100 it is 0.2 +- 0.04


def intermittent_case(kind: str, seed: int) -> dict:
    """A gripper that slips (or a part presented off its place) one cycle in five, from cycle AT.
    Its rate is scored against the rate it really had over the cycles watched (``realised``, what the
    record shows) and against the nominal 1 in 5."""
    fault = {"kind": kind, "at_cycle": AT, "rate": 0.2, "seed": seed, "dx_mm": 2.0}
    r = run(seed, AT - ACCEPTANCE + INTERMITTENT_CYCLES, [fault])
    d = _diagnose(r)
    expected = {"intermittent_slip": "tool_slip", "part_misplaced": "part_misplaced"}[kind]
    hit = [f for f in d.findings if f.rate is not None]
    true_hits = [i for i in range(AT, len(r.cycles)) if fault_hits(kind, i, seed)]
    realised = len(true_hits) / (len(r.cycles) - AT)
    named = hit[0] if hit else None
    right = bool(named and named.cause == expected)
    return {"kind": kind, "seed": seed, "expected": expected, "named": named.cause if named else None,
            "rate": named.rate if named else None, "realised_rate": realised,
            "first": named.cycle if named else None, "true_first": true_hits[0] if true_hits else None,
            "ok": right and abs(named.rate - realised) <= 0.10,
            "ok_nominal": right and abs(named.rate - 0.2) <= 0.10,
            "causes": [f.cause for f in d.findings]}


def fault_hits(kind: str, cycle: int, seed: int) -> bool:
    from cellguard.robot.faults.intermittent import hits
    return hits(cycle, AT, 0.2, seed)


QUADRUPED_CASES = {
    "servo_leg": ([{"kind": "servo_gain", "joint": ["rl_abduction", "rl_hip", "rl_knee"], "factor": 0.85,
                    "at_cycle": 20}], "servo", "rl"),
    "friction_knee": ([{"kind": "friction_step", "joint": "fr_knee", "factor": 1.5, "at_cycle": 20}],
                      "friction", "fr"),
}


def quadruped_case(name: str, seed: int) -> dict:
    faults, cause, leg = QUADRUPED_CASES[name]
    r = run(seed, 10, faults, cell="quadruped-turns", acceptance=20)
    d = _diagnose(r, symmetry=r.symmetry)
    right = [f for f in d.findings if f.cause == cause and leg in f.legs]
    wrong = [f for f in d.findings if f.cause != cause or leg not in f.legs]  # another cause, or on another leg
    return {"case": name, "seed": seed, "expected": [cause, leg], "ok": bool(right) and not wrong,
            "findings": [(f.cause, list(f.joints), list(f.legs)) for f in d.findings],
            "asymmetry": d.asymmetry.side if d.asymmetry else None}


def arl_check(seed: int = 0) -> dict:
    """Average run lengths by simulation next to the theory, on unit-variance Gaussian residuals.

    (1) One one-sided CUSUM at each reference value k in use, at thresholds for ARL0 500 and 5,000:
    Siegmund's approximation against the mean of simulated run lengths. (2) The whole monitor set
    of the arm (54 features, pooled channels, multivariate EWMA, with clipping) at a budget scaled
    down to 300 cycles (10^5 cannot be simulated here): the simulated run length of the set to its
    first false alarm against the budget.
    """
    rng = np.random.default_rng(seed)
    single = []
    for k in (1.0, 0.5):
        for target in (500.0, 5000.0):
            h = siegmund_threshold(target, k)
            runs = 2000
            s, length, alive = np.zeros(runs), np.zeros(runs), np.ones(runs, dtype=bool)
            while alive.any():
                s = np.where(alive, np.maximum(0.0, s + rng.standard_normal(runs) - k), s)
                length += alive
                alive &= s <= h
            single.append({"k": k, "h": round(h, 3), "theory": round(_siegmund_arl(h, k), 1),
                           "simulated": round(float(length.mean()), 1)})
    joints = ("j0", "j1", "j2", "j3", "j4", "j5")
    names = tuple(sorted([f"{s}.{j}" for s in ("current_peak", "current_rms", "tracking_rms", "tracking_max",
                                                   "grasp_q", "current_carry_rms") for j in joints]
                         + [f"other_{i}" for i in range(18)]))
    p = len(names)
    base = Baseline(names, {"": MotionStats(20, (0.0,) * p, (1.0,) * p, tuple(tuple(float(i == j) for j in range(p))
                                                                             for i in range(p)))}, (0, 19), 20, None)
    budget, horizon, lengths = 300.0, 3000, []
    config = DriftConfig(set_arl=budget)
    for _ in range(60):
        x = rng.standard_normal((horizon, p))
        cycles = [Cycle(i, "production", True, dict(zip(names, row))) for i, row in enumerate(x)]
        alarms = detect_drift(base, cycles, config).alarms
        lengths.append(alarms[0].cycle + 1 if alarms else horizon)
    return {"single_cusum": single, "set": {"features": p, "budget_cycles": budget,
                                            "simulated_mean_run_length": round(float(np.mean(lengths)), 1),
                                            "runs": len(lengths), "censored_at": horizon}}


def score(kind: str, r: Simulated) -> dict:
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
            "onset": after[0].cycle if after else None, "diagnose_s": elapsed,
            "findings": [(f.cause, list(f.joints), f.cycle) for f in d.findings]}


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
    case = {"power": power_case, "payload": payload_case, "warmup": warmup_case, "intermittent": intermittent_case,
            "quadruped": quadruped_case, "arl": arl_check}.get(task[0])
    if case is not None:
        result = case(*task[1:])
        print(f"{task}: {result}", file=sys.stderr, flush=True)
        return task, result
    if task[0] == "free":
        return task, fault_free(task[1], task[2])
    if task[0] == "hour":
        return task, one_hour()
    kind, level, magnitude, seed = task
    result = score(kind, run(seed, PRODUCTION, faults(kind, magnitude, seed)))
    print(f"{kind} {level} seed {seed}: {result}", file=sys.stderr, flush=True)
    return task, result


def one_hour() -> dict:
    """A recorded hour of the arm cell (about 810 cycles), then ``diagnose DIR`` on the record: wall and
    CPU time (median of five, the first of which writes the baseline beside the record), the load
    average while it ran (the machine may be shared) and the wall as a multiple of one ``mj_step``."""
    from cellguard.diagnose.from_record import BASELINE_FILE, diagnose_record
    from cellguard.robot.registry import make_cell
    from cellguard.runtime import run_scenario

    cycles = round(3600 / 4.444)
    raw = {"cell": "arm-pick-place", "seed": 5, "acceptance_cycles": ACCEPTANCE, "production_cycles": cycles - ACCEPTANCE,
           "faults": [{"kind": "fixture_shift", "at_cycle": 600, "dx_mm": 3.0}]}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "hour"
        kept = RUNS / f"hour-{hashlib.sha256(json.dumps(raw, sort_keys=True).encode()).hexdigest()[:16]}" if RUNS else None
        if kept is not None and kept.is_dir():
            shutil.copytree(kept, folder)
        else:
            run_scenario(parse_scenario(raw), folder)
            if kept is not None:
                shutil.copytree(folder, kept.with_suffix(".tmp"), dirs_exist_ok=True)
                kept.with_suffix(".tmp").replace(kept)
        (folder / BASELINE_FILE).unlink(missing_ok=True)
        walls, cpus, load = [], [], os.getloadavg()
        for _ in range(5):
            t0, c0 = time.perf_counter(), time.process_time()
            d = diagnose_record(folder)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        size = sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())
    cell = make_cell("arm-pick-place")
    data, steps = mujoco.MjData(cell.model), []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(1000):
            mujoco.mj_step(cell.model, data)
        steps.append((time.perf_counter() - t0) / 1000)
    wall, step = float(np.median(walls)), float(np.median(steps))
    return {"cycles": len(d.cycles), "record_bytes": size, "diagnose_record_s": round(wall, 3),
            "diagnose_record_cpu_s": round(float(np.median(cpus)), 3),
            "first_with_baseline_write_s": round(walls[0], 3), "walls_s": [round(w, 3) for w in walls],
            "load_average_1_5_15": [round(x, 2) for x in load], "mj_step_s": step,
            "diagnose_over_mj_step": round(wall / step), "findings": [f.to_dict()["cause"] for f in d.findings],
            "first_faulted_cycle": d.first_faulted_cycle}


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
    if not free:
        return "\n".join(lines)
    lines.append(f"| none (fault-free) | - | {len(free)} runs x {free[0]['production_cycles']} production cycles | "
                 f"- | - | - | {alarms} in {total} cycles |")
    return "\n".join(lines)


def _issue16_summary(res: dict) -> dict:
    out = {}
    for kind in ("servo", "friction"):
        rows = [r for r in res.get("power", []) if r["kind"] == kind]
        if rows:
            out[f"{kind}_small_named_within_{WITHIN}"] = f"{sum(r['named'] and r['delay'] is not None for r in rows)}/{len(rows)}"
            out[f"{kind}_small_delays"] = [r["delay"] for r in rows]
    for declared in (True, False):
        rows = [r for r in res.get("payload", []) if r["declared"] == declared]
        if rows:
            out[f"payload_{'declared' if declared else 'undeclared'}_ok"] = f"{sum(r['ok'] for r in rows)}/{len(rows)}"
    if res.get("warmup"):
        out["warmup_no_alarm"] = f"{sum(r['ok'] for r in res['warmup'])}/{len(res['warmup'])}"
    for kind in ("intermittent_slip", "part_misplaced"):
        rows = [r for r in res.get("intermittent", []) if r["kind"] == kind]
        if rows:
            out[f"{kind}_ok"] = f"{sum(r['ok'] for r in rows)}/{len(rows)}"
            out[f"{kind}_ok_nominal"] = f"{sum(r['ok_nominal'] for r in rows)}/{len(rows)}"
            out[f"{kind}_realised_rates"] = [round(r["realised_rate"], 3) for r in rows]
            out[f"{kind}_rates"] = [r["rate"] for r in rows]
    for r in res.get("quadruped", []):
        out[f"quadruped_{r['case']}_ok"] = r["ok"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--md", type=Path, default=None, help="write the markdown table here")
    ap.add_argument("--free-cycles", type=int, default=300)
    ap.add_argument("--kinds", nargs="*", default=list(EXPECTED))
    ap.add_argument("--cases", nargs="*", default=["power", "payload", "warmup", "intermittent", "quadruped", "arl"])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per issue-16 case (power: 9 at most used)")
    ap.add_argument("--free-seeds", type=int, default=3)
    ap.add_argument("--hour", action="store_true", help="also time diagnose on a recorded one-hour run")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--runs", type=Path, default=None,
                    help="keep simulated runs here and reuse them (re-score a changed diagnosis without simulating)")
    args = ap.parse_args()
    global RUNS
    RUNS = args.runs
    if RUNS is not None:
        RUNS.mkdir(parents=True, exist_ok=True)
    tasks = [("hour",)] if args.hour else []
    free_seeds = SEEDS[:args.free_seeds]
    tasks += [("free", seed, args.free_cycles) for seed in free_seeds]
    held_out = range(10, 10 + args.seeds)
    cases = {"power": [("power", k, s) for k in ("servo", "friction") for s in list(held_out)[:9]],
             "payload": [("payload", d, s) for d in (True, False) for s in held_out],
             "warmup": [("warmup", s) for s in held_out],
             "intermittent": [("intermittent", "intermittent_slip", s) for s in held_out]
                             + [("intermittent", "part_misplaced", s) for s in list(held_out)[:1]],
             "quadruped": [("quadruped", name, 10) for name in QUADRUPED_CASES], "arl": [("arl",)]}
    tasks += [t for c in args.cases for t in cases[c]]
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
                         "onsets": [r["onset"] for r in results], "findings": [r["findings"] for r in results],
                         "false_alarms": sum(r["false_alarms"] for r in results)})
    free = [done[("free", seed, args.free_cycles)] for seed in free_seeds]
    graded = [r for r in rows if r["level"] != "small"]
    summary = {
        "cause_accuracy_moderate_large": sum(r["correct"] for r in graded) / max(sum(r["n"] for r in graded), 1),
        "detection_rate_all": sum(r["detected"] for r in rows) / max(sum(r["n"] for r in rows), 1),
        "false_alarms_fault_free": sum(f["drift_alarms"] + len(f["findings"]) for f in free),
        "false_alarms_before_fault": sum(r["false_alarms"] for r in rows),
        "fixture_3mm_max_delay": max((d for r in rows if r["kind"] == "fixture_shift" and r["magnitude"] == 3.0
                                      for d in r["delays"] if d is not None), default=None),
    }
    issue16 = {c: [done[t] for t in cases[c]] for c in args.cases}
    summary.update(_issue16_summary(issue16))
    out = {"rows": rows, "fault_free": free, "summary": summary, "issue16": issue16}
    if args.hour:
        out["one_hour"] = done[("hour",)]
    md = table(rows, free)
    if args.md:
        args.md.write_text(md + "\n")
    print(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
