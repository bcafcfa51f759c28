"""Staged release: bundles, stages and pointers, gates, shadow mode, the hash-chained log.

    bundle.py     a release's manifest and id (hash of its canonical JSON); verify its inputs
    store.py      SQLite in the site's folder: bundles, (cell, stage) -> current / last_good, runs
    plan.py       per stage: the runs that make its evidence and its gates (YAML)
    metrics/      the metrics computed from the runs' records, one module per group, found by discovery
    gates.py      a condition on a metric: pass / fail / inconclusive; hard gates
    loops.py      how a stage's runs are driven (simulated time, wall time)
    shadow.py     pilot: the candidate beside the incumbent, never actuating
    log.py        the hash-chained promotion log and its verification
    promotion.py  promote, run a stage, roll back (by hand or when production's gates fail)
"""

from cellguard.release.bundle import Bundle, create_bundle, verify_bundle
from cellguard.release.log import verify_log
from cellguard.release.plan import load_plan
from cellguard.release.promotion import evaluate_stage, promote, rollback, run_stage, status
from cellguard.release.store import STAGES, Store

__all__ = ["STAGES", "Bundle", "Store", "create_bundle", "evaluate_stage", "load_plan", "promote", "rollback",
           "run_stage", "status", "verify_bundle", "verify_log"]
