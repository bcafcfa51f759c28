"""The real cellguard runs a simulated fleet is built from (cached; used by benchmarks/fleet.py).

24 sites of 4 tenants, each site two short production runs of the arm cell with one fault each
(kinds, magnitudes, joints and seeds vary by site), and 5 held-out runs that ``fleet similar``
is asked about. Every site's cell is the same model, commissioned once: one acceptance run is
the baseline every run is diagnosed against (``diagnose_record(run, acceptance=...)``), as a
fleet operator would ship one commissioning baseline with a standard cell. A production run is
one clean cycle, then two with the fault. Runs are made and diagnosed two at a time (2 cores);
a run folder is named by its scenario's hash, so a changed plan never reads a stale run. SIGTERM or
Ctrl-C cancels the queued jobs and waits for the running ones (a run they stopped is not kept): a
worker left behind waited on its queue for good. No job starts once any process of the pool was signalled
(``_stopping``): the jobs already in the pool's queue, up to three whole runs, were made after the signal. On
Linux a worker is killed when the script dies (SIGKILL, which no shutdown follows): its run's ``.partial``
folder is removed when the run is made again.

    python benchmarks/fleet_runs.py [DIR]     # makes the missing runs, prints what it did as JSON
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import hashlib
import json
import multiprocessing
import os
import shutil
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

CELL = "arm-pick-place"
ACCEPTANCE = 6  # cycles of the shared commissioning run (the baseline needs at least 5)
PRODUCTION, AT = 3, 1  # cycles of a site's run; the fault from this cycle on
TENANTS = ("t-alpha", "t-beta", "t-gamma", "t-delta")
SITES_PER_TENANT, RUNS_PER_SITE = 6, 2
DEFAULT_DIR = Path("out/fleet-runs")
PR_SET_PDEATHSIG = 1  # Linux prctl: the signal a process gets when the thread that forked it ends

# fault kind -> (cause it should read as, magnitudes a site draws from, joints it may hit)
KINDS = {
    "fixture_shift": ("fixture_shift", (3.0, 4.0, 5.0, 6.0), ()),
    "camera_shift": ("camera_shift", (2.5, 3.0, 4.0, 5.0), ()),
    "friction_step": ("friction", (1.8, 2.0, 2.5, 3.0), ("elbow", "shoulder_lift")),
    "servo_gain": ("servo", (0.5, 0.55, 0.6, 0.65), ("shoulder_lift", "elbow")),  # 0.75: unseen in 2 cycles
    "tool_slip": ("tool_slip", (2.5, 3.0, 4.0, 5.0), ()),
    "policy_latency": ("policy_latency", (200.0, 250.0, 300.0, 350.0), ()),
    "policy_nan": ("policy_output", (0.0,), ()),
    "part_misplaced": ("part_misplaced", (3.0, 4.0, 5.0, 6.0), ()),
}
HELD_OUT = [("fixture_shift", 4.5, ""), ("camera_shift", 3.5, ""), ("friction_step", 2.2, "elbow"),
            ("servo_gain", 0.65, "shoulder_lift"), ("policy_latency", 280.0, "")]


def fault(kind: str, size: float, joint: str = "") -> dict:
    """The scenario's fault entry: ``kind`` of magnitude ``size`` from cycle AT."""
    return {
        "fixture_shift": {"dx_mm": size, "dy_mm": size / 3},
        "camera_shift": {"dx_mm": size},
        "friction_step": {"joint": joint, "factor": size},
        "servo_gain": {"joint": joint, "factor": size},
        "tool_slip": {"dx_mm": size},
        "policy_latency": {"ms": size},
        "policy_nan": {},
        "part_misplaced": {"rate": 1.0, "dx_mm": size},
    }[kind] | {"kind": kind, "at_cycle": AT}


@dataclass(frozen=True)
class PlannedRun:
    name: str  # folder name: role, index, fault kind, scenario hash
    tenant: str  # "" for the acceptance and held-out runs
    site: str
    cause: str  # what the injected fault should read as ("" for acceptance)
    scenario: dict


def _run(role: str, i: int, tenant: str, site: str, cause: str, scenario: dict) -> PlannedRun:
    digest = hashlib.sha256(json.dumps(scenario, sort_keys=True).encode()).hexdigest()[:8]
    kind = scenario["faults"][0]["kind"] if scenario.get("faults") else "none"
    return PlannedRun(f"{role}-{i:02d}-{kind}-{digest}", tenant, site, cause, scenario)


def plan() -> tuple[PlannedRun, list[PlannedRun], list[PlannedRun]]:
    """(acceptance run, the 48 site runs, the 5 held-out runs). Tenant i's site j runs kinds
    2j+i and 2j+i+1 (mod 8): every tenant sees every kind, four of them twice (on both joints
    where the kind hits a joint), at magnitudes of its own."""
    acceptance = _run("acceptance", 0, "", "", "", {"cell": CELL, "seed": 7, "acceptance_cycles": ACCEPTANCE,
                                                    "production_cycles": 0})
    kinds = list(KINDS)
    sites = []
    for i, tenant in enumerate(TENANTS):
        for j in range(SITES_PER_TENANT):
            for r in range(RUNS_PER_SITE):
                n, m = len(sites), RUNS_PER_SITE * j + r + i  # m: the tenant's run, shifted by tenant
                kind, turn = kinds[m % len(kinds)], m // len(kinds)  # turn 1: the kind's second run here
                cause, sizes, joints = KINDS[kind]  # ... at another magnitude, on the other joint
                f = fault(kind, sizes[(i + j + 2 * turn) % len(sizes)], joints[turn % len(joints)] if joints else "")
                scenario = {"cell": CELL, "seed": 100 + n, "acceptance_cycles": 0, "production_cycles": PRODUCTION,
                            "site": f"s-{tenant[2:]}-{j}", "faults": [f]}
                sites.append(_run("site", n, tenant, f"s-{tenant[2:]}-{j}", cause, scenario))
    held = [_run("held", k, "", "s-new", KINDS[kind][0],
                 {"cell": CELL, "seed": 500 + k, "acceptance_cycles": 0, "production_cycles": PRODUCTION,
                  "faults": [fault(kind, size, joint)]})
            for k, (kind, size, joint) in enumerate(HELD_OUT)]
    return acceptance, sites, held


def _make(folder: Path, scenario: dict) -> tuple[float, float]:
    """Run the scenario into ``folder`` (beside it, then renamed): (wall, CPU) seconds; OperatorStopped if a signal
    stopped it, or came before it started (nothing is made then)."""
    from cellguard.errors import OperatorStopped
    from cellguard.runtime import Run, run_scenario
    from cellguard.runtime.operator_stop import by_operator
    from cellguard.scenario import parse_scenario

    t, c = time.perf_counter(), time.process_time()
    tmp = folder.with_name(folder.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    run = Run(parse_scenario(scenario))
    with run.operator:  # a signal from here on stops the run; one before (``_stopping``) keeps it from starting
        if _stopping.value:
            run.close()
            raise OperatorStopped(f"{folder.name}: not started, the pool is stopping")
        stopped = run_scenario(run.scenario, tmp, run=run).get("stopped")
    if by_operator(stopped):  # a signal cut it short: once renamed, it was read as the site's whole run
        _stopping.value = True  # no job starts after it in any worker (the signal went to the run, not ``_stop``)
        shutil.rmtree(tmp)
        raise OperatorStopped(f"{folder.name}: {stopped}")
    os.replace(tmp, folder)
    return time.perf_counter() - t, time.process_time() - c


def _signatures(folder: Path, acceptance: Path, tenant: str, site: str):
    """The run's signatures as ``tenant``/``site``, diagnosed against the shared acceptance run."""
    from cellguard.errors import OperatorStopped
    from cellguard.fleet.from_record import site_signatures
    from cellguard.fleet.policy import DataPolicy

    if _stopping.value:
        raise OperatorStopped(f"{folder.name}: not diagnosed, the pool is stopping")
    c = time.process_time()
    return site_signatures(folder, DataPolicy(tenant or "t-probe", site or "s-new"), acceptance=acceptance), \
        time.process_time() - c


def make_fleet(root: Path = DEFAULT_DIR, workers: int = 2) -> dict:
    """Make every missing run, then diagnose every run: {"site": {name: (run, signatures)},
    "held": {...}, "made": runs made now, "cpu_s": CPU seconds of the workers' jobs, ...}."""
    root.mkdir(parents=True, exist_ok=True)
    acceptance, sites, held = plan()
    acc = root / acceptance.name
    todo = [r for r in (acceptance, *sites, *held) if not (root / r.name / "summary.json").is_file()]
    t0 = time.perf_counter()
    out: dict = {"site": {}, "held": {}}
    pool = _pool(workers)
    with _ended_by_sigterm():
        try:
            made = list(pool.map(_make, [root / r.name for r in todo], [r.scenario for r in todo]))
            t_made = time.perf_counter() - t0
            groups = [("site", r) for r in sites] + [("held", r) for r in held]
            found = pool.map(_signatures, [root / r.name for _, r in groups], [acc] * len(groups),
                             [r.tenant for _, r in groups], [r.site for _, r in groups])
            for (group, r), (sigs, _) in zip(groups, found):
                out[group][r.name] = (r, sigs)
        finally:  # on a signal or an error too: the queued jobs cancelled, no worker outlives the script
            _stopping.value = True  # the jobs already queued in the pool: cancel_futures does not reach them
            pool.shutdown(cancel_futures=True)
    out.update(made=len(todo), runs=1 + len(sites) + len(held), acceptance=str(acc),
               make_cpu_s=sum(c for _, c in made), make_wall_s=t_made, wall_s=time.perf_counter() - t0)
    return out


_stopping = None  # shared by the pool's processes (``_pool``): true once one was signalled; no job starts then


def _pool(workers: int) -> ProcessPoolExecutor:
    """The pool the runs are made in: forked from this process whatever the default start method (forkserver from
    Python 3.14 on Linux made the workers' parent the server, and each ended at once in ``_worker_start``)."""
    global _stopping
    context = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else None)
    _stopping = context.RawValue(ctypes.c_bool, False)
    return ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_start,
                               initargs=(os.getpid(), _stopping))


def _worker_start(parent: int, stopping) -> None:
    """A pool worker's set-up. SIGTERM and SIGINT outside a run (which takes them as an operator stop) only stop
    its jobs (``_stop``): a worker they ended between two jobs broke the pool, whose clean-up (CPython 3.11) then
    made every job still queued in the surviving worker, a few whole runs, or waited for good on the queue's lock that
    the dead worker held while it waited for a job. On Linux it is killed when the parent dies (strictly, when the
    thread that forked it ends: pool.map's caller, which waits for the pool): a SIGKILLed script shuts no pool down,
    and its workers made runs for minutes, orphaned, then waited on their queue for good."""
    global _stopping
    _stopping = stopping
    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    if not sys.platform.startswith("linux"):
        return
    arg = ctypes.c_ulong
    if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, arg(signal.SIGKILL), arg(0), arg(0), arg(0)) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    if os.getppid() != parent:  # the parent died before the death signal was set
        os._exit(1)


def _stop(signum, frame) -> None:
    """A pool worker's SIGTERM or SIGINT: no job starts from now on, in any process of the pool."""
    _stopping.value = True


@contextlib.contextmanager
def _ended_by_sigterm():
    """SIGTERM raises SystemExit(143) in the main thread while the pool works, as Ctrl-C raises
    KeyboardInterrupt, so the pool is shut down on the way out (killed outright, the parent left its
    workers waiting on their queue)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def end(signum, frame):
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, end)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir", nargs="?", type=Path, default=DEFAULT_DIR,
                    help=f"folder of the cached runs (default {DEFAULT_DIR})")
    args = ap.parse_args()
    try:
        fleet = make_fleet(args.dir)
    except KeyboardInterrupt:
        print("fleet_runs: stopped by Ctrl-C; the runs made so far are kept", file=sys.stderr)
        sys.exit(130)
    read = {g: sum(r.cause in [s.cause for s in sigs] for r, sigs in fleet[g].values()) for g in ("site", "held")}
    print(json.dumps({k: v for k, v in fleet.items() if k not in ("site", "held")}
                     | {"read_as_injected": read, "site_runs": len(fleet["site"]), "held_runs": len(fleet["held"])},
                     default=str))


if __name__ == "__main__":
    main()
