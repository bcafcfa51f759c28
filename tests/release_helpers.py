"""Shared by the release tests: a small plan, the CLI, a replay policy file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from typer.testing import CliRunner

from cellguard.cli import app

CELL = "arm-pick-place"
runner = CliRunner()


def cli(*args: str):
    return runner.invoke(app, ["release", *args])


def write_plan(path: Path, stages: dict) -> Path:
    path.write_text(yaml.safe_dump({"stages": stages}))
    return path


ONE = {"name": "one", "seed": 5, "acceptance_cycles": 1}
KNOCKED = {"name": "knocked", "seed": 6, "acceptance_cycles": 1,
           "faults": [{"kind": "fixture_shift", "at_cycle": 0, "dx_mm": 10.0}]}  # fails its cycle


def sim_and_production_plan(tmp_path: Path, run: dict = ONE):
    """A plan of one run (``run``) and a success gate at sim and at production, loaded."""
    from cellguard.release import load_plan

    gates = [{"metric": "success_rate", "min": 1.0}]
    return load_plan(write_plan(tmp_path / "plan.yaml", {s: {"runs": [run], "gates": gates}
                                                         for s in ("sim", "production")}))


def stored_release(store, note: str) -> str:
    """A scripted release of the arm cell, ``note`` making it new, added to ``store``; its id."""
    from cellguard.release import create_bundle

    bundle = create_bundle("scripted", None, CELL, None, note=note)
    store.add_bundle(bundle)
    return bundle.id


def replay_file(path: Path, offset: float = 0.0) -> Path:
    """A replay policy file holding the arm's home pose (plus ``offset`` [rad] on every joint)."""
    from cellguard.robot.registry import make_cell

    q = make_cell(CELL).read().q + offset
    np.savez(path, t=np.array([0.0]), actions=np.tile(q, (1, 10, 1)), dt=np.array(0.05))
    return path


def pointers(site: Path) -> list:
    from cellguard.release import Store, status

    return status(Store(site))


def two_runs_at_sim(tmp_path: Path, cycles: int) -> tuple[Path, Path, str]:
    """A plan of two sim runs (``cycles`` acceptance cycles each, a gate that any run passes) and a site
    where the taught program's release is current at sim: (plan, site, release id)."""
    from cellguard.release import Store, create_bundle, promote

    runs = [{"name": name, "seed": 2, "acceptance_cycles": cycles} for name in ("first", "second")]
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": runs, "gates": [{"metric": "success_rate", "min": 0}]}})
    site = tmp_path / "site"
    store = Store(site)
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    return plan, site, bundle.id


def log_pass(store, stage: str, release: str) -> None:
    """A gates entry passing ``release`` at ``stage`` on the packaged plan, its pointers set as ``release run`` sets
    them (the first release to pass a stage is its own last_good): the earlier stages' gates, when their runs are
    not the point."""
    from cellguard.release import load_plan, log
    from cellguard.release.plan import PICK_PLACE_PLAN
    from cellguard.release.promotion import plan_hash

    with store.transaction():
        log.append(store, {"kind": "gates", "cell": CELL, "stage": stage, "release": release, "verdict": "pass",
                           "gates": [], "evidence": [], "plan_sha256": plan_hash(load_plan(PICK_PLACE_PLAN)[stage])})
        if store.pointers(CELL, stage).last_good is None:
            store.set_pointers(CELL, stage, release, release)


def to_production(store, release: str) -> None:
    """Promote ``release`` through every stage, the earlier stages' gates logged as passed (their runs are not the
    point)."""
    from cellguard.release import promote

    for stage, before in (("sim", None), ("bench", "sim"), ("pilot", "bench"), ("production", "pilot")):
        if before:
            log_pass(store, before, release)
        promote(store, release, CELL, stage)


def promoted_site(tmp_path: Path, notes=("v1",)) -> tuple[Path, list[str]]:
    """A site where each release (one per note) was promoted to sim in turn: (site, release ids)."""
    from cellguard.release import Store, create_bundle, promote

    site, ids = tmp_path / "site", []
    store = Store(site)
    for note in notes:
        bundle = create_bundle("scripted", None, CELL, None, note=note)
        store.add_bundle(bundle)
        promote(store, bundle.id, CELL, "sim")
        ids.append(bundle.id)
    store.close()
    return site, ids


def edit_store(site: Path, sql: str) -> None:
    """One SQL statement on the site's store, as an edit outside cellguard."""
    import sqlite3

    from cellguard.release.store import STORE_FILE

    db = sqlite3.connect(site / STORE_FILE)
    db.execute(sql)
    db.commit()
    db.close()


@dataclass(frozen=True)
class Received:
    """A chunk as the record holds it (``RecordedChunk``'s fields the gates read), for synthetic streams."""

    t_obs_ns: int
    t_received_ns: int
    latency_ns: int
    dt_ns: int
    actions: np.ndarray
