"""`cellguard release ...`: bundles, stages, gates, shadow mode, rollback and the hash-chained log."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console

from cellguard.cli import stdout
from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.errors import CellguardError

HELP = """Staged release of a policy on a cell: sim -> bench -> pilot (shadow) -> production.

\b
From download to production (the arm cell; every step logs to SITE/release.sqlite):
  cellguard train-demo-policy -o pick.onnx          # or your downloaded ONNX / LeRobot / openpi policy
  cellguard release create --policy onnx:pick.onnx --profile arm-pick-place --envelope guard.yaml
  cellguard release promote ID --cell arm-pick-place --to sim
  cellguard release run --cell arm-pick-place --stage sim          # the testnet, fault scenarios included
  cellguard release promote ID --cell arm-pick-place --to bench
  cellguard release run --cell arm-pick-place --stage bench        # wall-clock loop
  cellguard release promote ID --cell arm-pick-place --to pilot
  cellguard release run --cell arm-pick-place --stage pilot        # shadow: the incumbent drives
  cellguard release promote ID --cell arm-pick-place --to production
  cellguard release run --cell arm-pick-place --stage production   # a failing gate rolls back to last_good
  cellguard release status; cellguard release verify; cellguard release report ID -o release.html
"""

release_app = typer.Typer(no_args_is_help=True, help=HELP)
app.add_typer(release_app, name="release")

SITE = typer.Option(Path("cellguard-site"), "--site", envvar="CELLGUARD_SITE",
                    help="The site's folder: release store, run records.")
PLAN = typer.Option(None, "--plan", help="Release plan YAML (default: SITE/release-plan.yaml, else the packaged one "
                                         "for the cell's kind: a pick-place cell's, or any other cell's).")
out = Console()
err = Console(stderr=True)


def _store(site: Path, create: bool = False):
    """The site's store; ``create=True`` for ``release create`` alone: every other command refuses a site with none
    (a mistyped --site became an empty store, and ``rollback`` there said only "nothing to roll back to")."""
    from cellguard.release import Store

    return Store(site, create)


def _plan(site: Path, plan: Path | None, cell: str):
    """``--plan``, else the plan in force: the site's plan, else the packaged plan for the cell's kind."""
    from cellguard.release.plan import load_plan, plan_in_force

    return plan_in_force(site, cell) if plan is None else load_plan(plan)


def _plans(site: Path, plan: Path | None, cell: str) -> tuple:
    """(the plan the command takes, the plan in force): ``--plan``, else the plan in force; the site's
    release-plan.yaml, else the packaged plan for the cell's kind. ``run`` and ``promote`` both take last_good under
    the plan in force, whatever --plan: under ``promote --plan`` a weak plan's pass became the rollback target."""
    given = _plan(site, plan, cell)
    return given, given if plan is None else _plan(site, None, cell)


@release_app.command()
def create(
    policy: str = typer.Option(..., "--policy", help="Policy spec: scripted, onnx:FILE, lerobot:DIR, openpi:ws://..."),
    action_map: Path = typer.Option(None, "--map", help="Action map YAML (the policy's actions onto this robot)."),
    profile: str = typer.Option(..., "--profile", help="A cell's name for its own profile, or a profile YAML: the "
                                                      "cell's own, or a calibration of it (identify --write)."),
    envelope: Path = typer.Option(None, "--envelope", help="Envelope settings YAML (a scenario's guard: section)."),
    note: str = typer.Option("", "--note", help="Free text kept in the manifest."),
    site: Path = SITE,
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Freeze a policy, its action map, the profile and the envelope into a release bundle."""
    from cellguard.release import create_bundle

    try:
        bundle = create_bundle(policy, action_map, profile, envelope, note)
        store = _store(site, create=True)
        new = store.add_bundle(bundle)
        if new:
            stdout.written(f"release {bundle.id} in {site}")
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"id": bundle.id, "new": new, "manifest": bundle.manifest}) + "\n")
        return
    calibrated = f" calibrated by {bundle.calibration}" if bundle.calibration else ""
    out.print(f"release {bundle.id} ({'created' if new else 'already there, unchanged'}): "
              f"{bundle.manifest['policy']['spec']} on {bundle.cell}{calibrated}")


@release_app.command()
def promote(
    release: str = typer.Argument(..., help="Release id (a unique prefix is enough)."),
    cell: str = typer.Option(..., "--cell"),
    to: str = typer.Option(..., "--to", help="sim, bench, pilot or production: only the stage after one passed."),
    plan: Path = PLAN,
    site: Path = SITE,
) -> None:
    """Make a release current at a stage, from the stage before it with its gates passed, and its plan there one the
    cell can run. --plan: the plan that pass must have run, and the stage's runs; last_good is the plan in force's
    (the site's plan, else the packaged one), as for `release run`."""
    from cellguard.release import promote as do
    from cellguard.release.promotion import last_good_note

    try:
        store = _store(site)
        entry = do(store, release, cell, to, *_plans(site, plan, cell))
        stdout.written(f"log entry {entry.seq} ({entry.body['release']} current at {to} on {cell})")
        note = last_good_note(store, entry)
    except CellguardError as exc:
        fail(exc)
    before = f"was {entry.body['from']}" if entry.body["from"] else "the first here"
    out.print(f"{entry.body['release']} is current at {to} on {cell} ({before}); {note}; log entry {entry.seq}")


@release_app.command("run")
def run_stage(
    cell: str = typer.Option(..., "--cell"),
    stage: str = typer.Option(..., "--stage"),
    plan: Path = PLAN,
    scenario: Path = typer.Option(None, "--scenario", help="One run (scenario keys without cell, policy, guard) "
                                                          "instead of the plan's runs, e.g. with a fault: its "
                                                          "verdict is logged and moves nothing (no rollback)."),
    site: Path = SITE,
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Run a stage's plan with its current release and evaluate its gates (production: roll back on fail). A verdict
    under --plan acts (a pass makes its release last_good, a fail rolls back) only where that stage's part is the
    plan in force's (the site's plan, else the packaged one); one on --scenario's run never does."""
    from cellguard.release import run_stage as do
    from cellguard.release.errors import GateError
    from cellguard.release.plan import check_run, run_beside
    from cellguard.release.store import check_stage
    from cellguard.yaml_file import read_yaml

    try:
        plans, in_force = _plans(site, plan, cell)
        runs = None
        if scenario is not None:
            from cellguard.scenario import scenario_folder

            # its files beside the run's file
            runs = [run_beside(read_yaml(scenario, "run", GateError), scenario_folder(scenario), str(scenario))]
            check_run(runs[0], str(scenario))
        result = do(_store(site), plans[check_stage(stage)], cell, stage, runs,
                    on_run=None if as_json else err.print, in_force=in_force[stage])
        rolled = f", rolled back to {result.rolled_back_to}" if result.rolled_back_to else ""
        stdout.written(f"log entry {result.log_seq} ({stage} gates on {cell}: {result.verdict}{rolled}) with its "
                       f"records in {Path(result.folders[0]).parent}")
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"cell": cell, "stage": stage, "release": result.release,
                                     "verdict": result.verdict, "gates": [g.to_dict() for g in result.gates],
                                     "evidence": list(result.evidence), "refused": list(result.refused),
                                     "rolled_back_to": result.rolled_back_to, "log_seq": result.log_seq,
                                     "counted": result.counted, "acts": result.acts}) + "\n")
    else:
        for g in result.gates:
            value = "-" if g.value is None else f"{g.value:.4g}"
            out.print(f"  {g.status:<12} {g.metric:<26} {value:>10}  {g.condition}  {g.detail}")
            for e in g.evidence[:3] if g.status != "pass" else ():
                out.print(f"               evidence: {e}")
        for why in result.refused:
            out.print(f"  not read as evidence: {why}")
        out.print(f"{stage} on {cell}, release {result.release}: {result.verdict} (log entry {result.log_seq}; "
                  f"records {', '.join(result.evidence)})")
        if result.rolled_back_to:
            out.print(f"rolled back: production on {cell} is {result.rolled_back_to} again (last_good)")
        elif stage == "production" and result.verdict == "fail" and result.acts:
            out.print(f"nothing to roll back to: {result.release} stays current at production on {cell} (no other "
                      f"release is last_good there)")
        if not result.acts:
            out.print(_moves_nothing(result, scenario, plan))
    if result.verdict != "pass":
        raise typer.Exit(1)


def _moves_nothing(result, scenario: Path | None, plan: Path | None) -> str:
    """The line saying that ``result``'s verdict was logged and moved nothing (``promotion.acts``): its runs were
    ``--scenario``'s, or ``--plan`` is not the stage's part of the plan in force. A production fail there rolled
    back with nothing said."""
    stage = result.stage
    if scenario is not None:
        why = f"{scenario} ran in place of the plan's runs"
    else:
        why = f"--plan {plan}: not the plan in force at {stage} (the site's release-plan.yaml, else the packaged plan)"
    if result.verdict == "pass":
        then = ("this pass is logged, not evidence a promotion accepts" if scenario is not None else
                "this pass is logged and makes no release last_good; a promotion takes it only under the same --plan")
    elif stage == "production" and result.verdict == "fail":
        then = (f"this fail is logged and rolls nothing back: {result.release} stays current at production "
                f"(`release rollback` rolls back by hand)")
    else:
        then = f"this {result.verdict} verdict is logged and moves nothing"
    return f"  {why}: {then}"


@release_app.command()
def rollback(
    cell: str = typer.Option(..., "--cell"),
    stage: str = typer.Option("production", "--stage"),
    reason: str = typer.Option("operator", "--reason"),
    site: Path = SITE,
) -> None:
    """Move a stage's current release back to its last_good; the next run there records the switch."""
    from cellguard.release import rollback as do

    try:
        entry = do(_store(site), cell, stage, reason=reason)
        stdout.written(f"log entry {entry.seq} ({stage} on {cell} back to {entry.body['to']})")
    except CellguardError as exc:
        fail(exc)
    out.print(f"{stage} on {cell}: {entry.body['from']} -> {entry.body['to']} (last_good); log entry {entry.seq}")


@release_app.command()
def status(site: Path = SITE, as_json: bool = typer.Option(False, "--json")) -> None:
    """Every cell's stages: current, last_good and the latest verdict (a pass that lets nothing on under the plan in
    force now says why; a plan in force that does not load is named, not refused: status only reads)."""
    from cellguard.release import status as do

    try:
        rows = do(_store(site))
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps({"site": str(site), "stages": rows}) + "\n")
        return
    if not rows:
        out.print("no release promoted yet")
    for r in rows:
        verdict = f"{r['verdict']} ({r['not_counted']})" if r["not_counted"] else r["verdict"] or ""
        out.print(f"{r['cell']:<18} {r['stage']:<11} current {r['current'] or '-':<17} "
                  f"last_good {r['last_good'] or '-':<17} {verdict}")
    broken: dict[str, dict] = {}  # error -> the cells it stops, in order: a site's plan stops every cell alike
    for r in rows:
        if r["plan_error"]:
            broken.setdefault(r["plan_error"], {})[r["cell"]] = None
    for error, cells in broken.items():
        where = " for the stages named" if error.startswith("stage ") else ""  # a units file gone stops its stage
        out.print(f"{', '.join(cells)}: the plan in force does not load{where}, so nothing is promoted or run there "
                  f"until it does: {error}", markup=False, soft_wrap=True)


@release_app.command()
def verify(
    site: Path = SITE,
    expect_head: str = typer.Option(None, "--expect-head", help="A head hash kept outside the site (printed by an "
                                                                 "earlier verify): the log must still hold it."),
    as_json: bool = typer.Option(False, "--json"),
) -> None:
    """Check the promotion log's hash chain, the bundles, and the files (policy, action map, calibration) and profile
    that each release current or last_good at a stage froze; exit 1 naming each edited or deleted entry and each
    input changed since create, unreadable, or hashed by another cellguard version. A served policy is not contacted,
    one needing an extra not installed here is said not checked; a release neither current nor last_good is not
    checked (its files may be gone)."""
    from cellguard.release import verify_log
    from cellguard.release.bundle import check_live_inputs
    from cellguard.release.log import head, size

    try:
        store = _store(site)
        problems, n, last = verify_log(store, expect_head), size(store), head(store)
        inputs = check_live_inputs(store)
    except CellguardError as exc:
        fail(exc)
    files = [str(c) for c in inputs.changed]
    if as_json:
        sys.stdout.write(json.dumps({"entries": n, "head": last, "ok": not (problems or files),
                                     "problems": problems + files, "log_ok": not problems,
                                     "inputs": inputs.to_dict()}) + "\n")
    else:
        for p in problems:  # the chain's result, then the files' (_print_inputs): each said whatever the other's
            out.print(f"broken: {p}", markup=False, soft_wrap=True)
        if not problems:
            out.print(f"log whole: {n} entries, chain verified; head {last} (keep it elsewhere: --expect-head)",
                      soft_wrap=True)
        _print_inputs(inputs)
    if problems or files:
        raise typer.Exit(1)


def _print_inputs(inputs) -> None:
    """What ``verify`` found of the releases' files (each problem), checked and did not, each in one line."""
    from cellguard.release.bundle import REASONS

    for changed in inputs.changed:
        out.print(f"broken: {changed}", markup=False, soft_wrap=True)
    found = [f"{len(inputs.by_reason(r))} {words}" for r, words in REASONS.items() if inputs.by_reason(r)]
    out.print(f"files of the releases current or last_good at a stage ({len(inputs.releases)} checked: policy, action "
              f"map, profile, calibration): {', '.join(found) or 'whole'}; releases neither current nor last_good: "
              f"{inputs.idle}, not checked", markup=False, soft_wrap=True)
    for line in inputs.unchecked:
        out.print(line, markup=False, soft_wrap=True)


@release_app.command()
def report(
    release: str = typer.Argument(..., help="Release id (a unique prefix is enough)."),
    output: Path = typer.Option(Path("release.html"), "--out", "-o", help="HTML file to write; a file there is "
                                "replaced only if it is a page cellguard wrote (or empty)."),
    site: Path = SITE,
) -> None:
    """The release page: gates per stage with their evidence, against last_good's figures."""
    from cellguard.report.release import write_release_page

    try:
        path = write_release_page(_store(site), release, output)
        stdout.written(f"the release page {path}")
    except CellguardError as exc:
        fail(exc)
    out.print(f"release page: {path}")
