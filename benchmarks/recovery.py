"""Recovery benchmark (issue 13): what recoveries do for an intermittent gripper slip, and whether a
late recovery is named ``recovery`` from its record.

1. ``slip``: per seed one run with an intermittent slip and no recovery, one with ``retry_grasp``
   (escalating to an operator); success rate of the production cycles of each; and, read back from
   the record, that every recovery attempt of the run is there with its outcome.
2. ``late``: per seed a run with parts presented out of place now and then, in acceptance and
   production (so acceptance has recoveries to compare with), re-registered from the camera, and a
   ``late_recovery`` fault from ``--late-at`` on; the record is diagnosed (which sees only cycles
   and events) and scored: a ``recovery`` finding from the late fault's cycle on, and no
   ``tool_slip`` or ``fixture_shift`` finding (neither was injected: naming one is a confusion).

Prints one JSON document. Seeds 100 on are held out of the tests.

    .venv/bin/python benchmarks/recovery.py [--seeds 10] [--acceptance 6] [--production 8] [--late-at 7]
        [--cases slip late] [--workers 1]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from cellguard.diagnose.from_record import diagnose_record
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

RETRY = {"behaviours": [{"do": "retry_grasp", "trigger": "grasp_missed", "attempts": 2, "then": "operator"},
                        {"do": "operator", "hold_s": 0.5}]}
REREGISTER = {"behaviours": [{"do": "reregister_datum", "trigger": "grasp_missed", "attempts": 2, "then": "operator"},
                             {"do": "operator", "hold_s": 0.5}]}
CONFUSED = ("tool_slip", "fixture_shift")


def _scenario(seed: int, args, recovery: bool, late: bool) -> dict:
    if late:
        faults = [{"kind": "part_misplaced", "rate": args.rate, "dx_mm": 8.0, "seed": seed},
                  {"kind": "late_recovery", "at_cycle": args.late_at, "speed_scale": 0.5}]
    else:
        faults = [{"kind": "intermittent_slip", "rate": args.rate, "dx_mm": -5.0, "seed": seed}]
    policy = REREGISTER if late else RETRY
    return {"cell": "arm-pick-place", "seed": seed, "acceptance_cycles": args.acceptance,
            "production_cycles": args.production, "faults": faults, **({"recovery": policy} if recovery else {})}


def _slip(job) -> dict:
    seed, args = job
    out = {"seed": seed}
    with tempfile.TemporaryDirectory() as tmp:
        for name, recovery in (("without", False), ("with", True)):
            folder = Path(tmp) / name
            summary = run_scenario(parse_scenario(_scenario(seed, args, recovery, late=False)), folder)
            prod = [c for c in summary["cycles"] if c["phase"] == "production"]
            out[name] = {"cycles": len(prod), "succeeded": sum(c["success"] for c in prod)}
            if recovery:
                logged = [r for c in summary["cycles"] for r in c.get("recovery_log", [])]
                read = diagnose_record(folder).recoveries  # read back from the record's cycles (their recovery_log)
                out["recoveries"] = len(logged)
                out["recorded_with_outcome"] = sum(1 for r in read if r.get("outcome"))
                out["record_matches_run"] = ([(r["behaviour"], r["outcome"]) for r in read]
                                             == [(r["behaviour"], r["outcome"]) for r in logged])
    return out


def _late(job) -> dict:
    seed, args = job
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "late"
        run_scenario(parse_scenario(_scenario(seed, args, recovery=True, late=True)), folder)
        d = diagnose_record(folder).to_dict()
    findings = d["findings"]
    named = [f for f in findings if f["cause"] == "recovery" and f["cycle"] >= args.late_at]
    confused = [f["cause"] for f in findings if f["cause"] in CONFUSED]
    return {"seed": seed, "named_recovery": bool(named), "confused_with": confused,
            "correct": bool(named) and not confused, "findings": [(f["cause"], f["cycle"]) for f in findings],
            "evidence": named[0]["evidence"][:3] if named else []}


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--acceptance", type=int, default=6)
    p.add_argument("--production", type=int, default=8)
    p.add_argument("--late-at", type=int, default=7)
    p.add_argument("--rate", type=float, default=0.4, help="share of cycles the gripper slips (or a part is misplaced) in")
    p.add_argument("--cases", nargs="+", default=["slip", "late"], choices=["slip", "late"])
    p.add_argument("--workers", type=int, default=1)
    args = p.parse_args(argv)
    seeds = range(100, 100 + args.seeds)
    report: dict = {"settings": {k: v for k, v in vars(args).items() if k != "cases"}}
    began = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:  # its workers may fork (a run's record writer); Pool's may not
        if "slip" in args.cases:
            rows = list(pool.map(_slip, [(s, args) for s in seeds]))
            total = {k: sum(r[k]["cycles"] for r in rows) for k in ("without", "with")}
            ok = {k: sum(r[k]["succeeded"] for r in rows) for k in ("without", "with")}
            report["slip"] = {
                "success_rate_without": round(ok["without"] / total["without"], 4),
                "success_rate_with": round(ok["with"] / total["with"], 4),
                "production_cycles": total["with"], "recoveries": sum(r["recoveries"] for r in rows),
                "recorded_with_outcome": sum(r["recorded_with_outcome"] for r in rows),
                "record_matches_run": all(r["record_matches_run"] for r in rows), "runs": rows}
        if "late" in args.cases:
            rows = list(pool.map(_late, [(s, args) for s in seeds]))
            report["late"] = {"seeds": len(rows), "named_recovery": sum(r["named_recovery"] for r in rows),
                              "correct": sum(r["correct"] for r in rows), "runs": rows}
    report["wall_s"] = round(time.perf_counter() - began, 1)
    json.dump(report, sys.stdout, indent=1)
    sys.stdout.write("\n")
    return report


if __name__ == "__main__":
    main()
