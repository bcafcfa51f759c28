"""Promote, run a stage, roll back: every pointer move is a log entry in the same transaction.

As Kargo's stages: a release enters a stage only from the stage before it, and only when its
last gate evaluation there passed (``sim`` is entered from nothing). ``run_stage`` runs the
stage's plan with the stage's ``current`` release, evaluates the gates on those runs (against
``last_good``'s runs on the same stage), logs the result with the record ids, and in production
rolls ``current`` back to ``last_good`` on a fail that counts (``acts``: a fail under an ad-hoc
``--plan`` or on ``--scenario`` runs rolled production back). ``last_good`` is the release that passed there
before the current one: a promotion moves it to the outgoing release when that one had passed
(the first release to pass a stage is its own last_good). A pass counts, for a promotion and for
``last_good`` alike, only on the stage's part of the plan in force (``log.passed``): a weak ad-hoc
plan's pass made its release a rollback target. A verdict rests only on runs made as the plan it
evaluates makes them, its own release's and last_good's alike (``runs_key``: the plan but its
gates): three one-cycle runs of an ad-hoc plan, counted in the next evaluation under the plan in
force, turned its failing production verdict into a pass; a gate added to the plan in force keeps
every run comparable (keyed by the whole plan, it dropped last_good's runs and production no
longer rolled back).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

from cellguard.errors import CellguardError, OperatorStopped, OutputError, RecordError
from cellguard.output import make_folder
from cellguard.release import log
from cellguard.release.bundle import Bundle, calibration_file, canonical_json, verify_bundle
from cellguard.release.errors import BundleMismatch, GateError, ReleaseError, StageError
from cellguard.release.evidence import RunEvidence, counted_run, record_id
from cellguard.release.gates import FAIL, INCONCLUSIVE, PASS, GateResult, evaluate, verdict
from cellguard.release.kept import Kept
from cellguard.release.loops import CLOCKS
from cellguard.release.plan import StagePlan, check_cell, plan_in_force, robot_file_paths, robot_files, scenario_for
from cellguard.release.store import STAGES, RunRow, Store, check_stage

INCUMBENT_FALLBACK = "scripted"  # the cell's taught program: what a cell runs before any release


@dataclass(frozen=True)
class Start:
    """What a stage's runs started on: its pointers and the log entry that last moved it. Its gates are logged, and
    act, only if the stage is still so when they are: evaluated against a release a racing command made current
    since, a failing run rolled back the newcomer and a passing one undid its promotion."""

    current: str | None
    last_good: str | None
    move_seq: int


@dataclass(frozen=True)
class StageResult:
    cell: str
    stage: str
    release: str
    verdict: str
    gates: tuple[GateResult, ...]
    evidence: tuple[str, ...]  # record ids
    refused: tuple[str, ...]  # counted runs not read as evidence, each naming its folder and why
    folders: tuple[str, ...]
    rolled_back_to: str | None
    log_seq: int
    counted: bool  # a pass a promotion and last_good take (``log.passed``)
    acts: bool  # a verdict that may move a pointer (``acts``): else logged and acted on by nothing


def last_evaluation(store: Store, cell: str, stage: str, release: str) -> log.LogEntry | None:
    for entry in reversed(log.entries(store)):
        b = entry.body
        if b.get("kind") == "gates" and (b.get("cell"), b.get("stage"), b.get("release")) == (cell, stage, release):
            return entry
    return None


def promote(store: Store, release: str, cell: str, to: str, plans: dict[str, StagePlan] | None = None,
            in_force: dict[str, StagePlan] | None = None) -> log.LogEntry:
    """Make ``release`` current at (cell, to); StageError (nothing moved) when out of order, when its pass at the
    stage before ran another plan there than ``plans`` (every stage's) holds, or when ``plans`` has no runs at
    ``to``; GateError when ``to``'s plan holds a run or gate the cell cannot carry out (``check_cell``). The
    outgoing release becomes last_good only if its latest gates at ``to`` under ``in_force``'s part there (the plan
    in force, as ``run_stage`` takes it; default ``plans``) passed (``log.Judged``): ``promote --plan`` with a weak
    plan made a weak pass the rollback target. ``plans`` None: no plan is checked."""
    check_stage(to)
    bundle = store.bundle(release)
    if bundle.cell != cell:
        raise ReleaseError(f"--cell {cell}: release {bundle.id} was built for cell {bundle.cell!r}")
    verify_bundle(bundle)
    evaluation = None
    i = STAGES.index(to)
    if i > 0:
        prev = STAGES[i - 1]
        evaluation = last_evaluation(store, cell, prev, bundle.id)
        if evaluation is None:
            raise StageError(f"--to {to}: release {bundle.id} has no gate results at {prev} on {cell}; a stage is "
                             f"entered only from the one before it ({' -> '.join(STAGES)})")
        if evaluation.body.get("scenario"):
            raise StageError(f"--to {to}: the gates of {prev} for release {bundle.id} were evaluated on runs given "
                             f"with --scenario ({', '.join(evaluation.body['scenario'])}; log entry {evaluation.seq}), "
                             f"not on the plan's runs that define the stage: run {prev} with its plan first")
        if evaluation.body["verdict"] != PASS:
            failing = [g["metric"] for g in evaluation.body["gates"] if g["status"] != PASS]
            failing += ["runs not read as evidence"] if evaluation.body.get("refused") else []
            raise StageError(f"--to {to}: the gates of {prev} ended {evaluation.body['verdict']} for release "
                             f"{bundle.id} ({', '.join(failing)}; log entry {evaluation.seq})")
        if plans is not None:
            _check_plan(evaluation, plans[prev], to)
        unbound = log.run_problems(store, [evaluation])
        if unbound:
            raise ReleaseError(f"--to {to}: {unbound[0]}; nothing moved")
    in_force = plans if in_force is None else in_force
    in_force = None if in_force is None else plan_key(in_force[to])
    if plans is not None:
        plan = plans[to]
        if not plan.runs:  # a dead end: ``release run`` refuses the stage, so nothing could pass it
            raise StageError(f"--plan: stage {to} has no runs, so `release run --stage {to}` could gather no "
                             f"evidence there; give the stage runs and gates; nothing moved")
        check_cell(plan, cell, to)
    with store.transaction():  # the pointers read under the write lock: a racing promotion sees this one's
        current, last_good = log.check_pointers(store, cell, to)
        if current == bundle.id:
            raise StageError(f"--to {to}: release {bundle.id} is already current at {to} on {cell}")
        judged = log.Judged(log.entries(store))
        if current is not None and judged.why_not(cell, to, current, in_force) is None:
            last_good = current
        outgoing = judged.under(cell, to, current, in_force) if current is not None else None
        store.set_pointers(cell, to, bundle.id, last_good)
        return log.append(store, {"kind": "promote", "cell": cell, "stage": to, "release": bundle.id,
                                  "from": current, "to": bundle.id, log.IN_FORCE: in_force,
                                  log.OUTGOING: outgoing.seq if outgoing else None,
                                  "gates": evaluation.body["gates"] if evaluation else [],
                                  "evidence": evaluation.body["evidence"] if evaluation else [],
                                  "gates_entry": evaluation.seq if evaluation else None})


def _check_plan(evaluation: log.LogEntry, plan: StagePlan, to: str) -> None:
    """StageError unless the pass ``evaluation`` logged ran ``plan``, its stage's part of the plan in force: the
    runs and gates of another plan (``release run --plan``) do not define the stage. The stage's part, not the
    whole file: a later stage's edit changes nothing its runs showed, and is checked when that stage is left. An
    entry without the hash (an older cellguard) cannot show its plan: refused as well. The plan as written with
    what the files its runs name hold (``plan_key``): a pass under one units map did not define the stage under an
    edited one; such a refusal names the files (``files_edit``)."""
    b, now = evaluation.body, plan_key(plan)
    if log.ran_plan(b, now):
        return
    where = f"--to {to}: the gates of {b['stage']} for release {b['release']} passed"
    edited = files_edit(plan, b)
    if edited:
        raise StageError(f"{where} on this plan as written (log entry {evaluation.seq}), but {edited}; its runs "
                         f"define the stage: run {b['stage']} again with what its files hold now; nothing moved")
    logged = b.get("plan_sha256")
    ran = f"plan {str(logged)[:12]}" if logged else "a plan it did not log (an older cellguard)"
    raise StageError(f"{where} on {ran} for {b['stage']} (log entry {evaluation.seq}); the plan in force has "
                     f"{now[:12]} there, and its runs define the stage: run {b['stage']} with it first; nothing moved")


def files_edit(plan: StagePlan, body: dict) -> str | None:
    """Why the gates entry ``body``, which ran ``plan`` as written, did not run it (``plan_key``), in words: what
    the files its runs name held then; None where it ran another text. Every file is named: an entry logs what
    they held together, so which one changed is not known."""
    paths = robot_file_paths(plan.runs_beside())
    if body.get("plan_sha256") != plan_hash(plan) or not paths:
        return None
    text_only = _with_files(plan.model_dump(mode="json", exclude={"gates"}), [])  # RUNS before c40742b: no files
    if body.get(log.RUNS) in (None, text_only):
        return f"what {' and '.join(paths)} held then was not logged (an older cellguard)"
    return f"{' or '.join(paths)} held other contents then"


def rollback(store: Store, cell: str, stage: str, reason: str = "operator", automatic: bool = False,
             gates: list | None = None, evidence: list | None = None) -> log.LogEntry:
    """Move (cell, stage)'s ``current`` back to ``last_good``; call inside a transaction or alone (then it
    opens one, so the pointers are read under the write lock)."""
    if not store.db.in_transaction:
        with store.transaction():
            return rollback(store, cell, stage, reason, automatic, gates, evidence)
    current, last_good = log.check_pointers(store, cell, check_stage(stage))
    if last_good is None or last_good == current:
        raise StageError(f"--stage {stage}: nothing to roll back to on {cell} (current {current}, "
                         f"last_good {last_good})")
    body = {"kind": "rollback", "cell": cell, "stage": stage, "release": last_good, "from": current,
            "to": last_good, "automatic": automatic, "reason": reason, "gates": gates or [],
            "evidence": evidence or []}
    store.set_pointers(cell, stage, last_good, last_good)
    return log.append(store, body)


def run_stage(store: Store, plan: StagePlan, cell: str, stage: str, runs: list[dict] | None = None,
              on_run: Callable[[str], None] | None = None, in_force: StagePlan | None = None) -> StageResult:
    """Run the stage's plan (or ``runs``) with its current release, evaluate its gates, act on the verdict.
    ``in_force``: the stage's part of the plan in force, when ``plan`` is another (``evaluate_stage``).

    A run the operator stopped, or one whose record could not be written, is no evidence about the
    release: it is not counted, no later run starts and no gate is evaluated (OperatorStopped,
    RecordError). Counted, a full disk's partial run could fail production's gates and roll back a
    release that had done nothing wrong."""
    from cellguard.runtime import run_scenario
    from cellguard.runtime.operator_stop import by_operator

    log.tail(store)  # a log edited by hand: refused before anything runs, as its gates could not be logged
    current, last_good = log.check_pointers(store, cell, check_stage(stage))  # a pointer edited by hand: same
    if current is None:
        raise StageError(f"--stage {stage}: no release is current at {stage} on {cell}; promote one first")
    bundle = store.bundle(current)
    verify_bundle(bundle)
    incumbent = _incumbent(store, cell) if plan.shadow else None
    entries = runs if runs is not None else plan.runs_beside()
    if not entries:
        raise StageError(f"--stage {stage}: the plan has no runs for {stage}")
    if not plan.gates:
        raise StageError(f"--stage {stage}: the plan has no gates for {stage}; its runs could only end inconclusive")
    check_cell(plan, cell, stage, entries)  # every run, before the first starts
    _judged_by(plan, runs, in_force)  # a units map its runs need unreadable: refused before the first run
    moved = log.last_pointer_move(store, cell, stage)
    start = Start(current, last_good, moved.seq if moved else 0)
    context = {"id": bundle.id, "cell": cell, "stage": stage, **bundle.short(),
               "switch": {k: moved.body.get(k) for k in ("kind", "from", "to", "automatic", "reason")}
               | {"log_seq": moved.seq, "at": moved.body["at"]} if moved else None}
    make = _maker(plan, bundle, incumbent, context)
    folders = []
    for entry in entries:
        name = entry.get("name", "run")
        scenario = scenario_for(entry, cell, *_driver(plan, bundle, incumbent), _calibration(bundle),
                                origin=f"{stage} run")
        folder = _claim_folder(store, cell, stage, name)
        if on_run is not None:
            on_run(f"{stage}: {name} ({scenario.total_cycles} cycles) -> {folder}")
        try:
            run = _start(make, scenario, bundle, incumbent, plan.shadow)
        except BaseException:
            folder.rmdir()  # claimed, nothing recorded in it
            raise
        run_scenario(scenario, folder, run=run)
        if by_operator(run.stopped):  # not evidence about the release: not counted, nothing else run or evaluated
            whole = f"could not be written whole ({run.recording.failed})" if run.recording.failed else "is complete"
            raise OperatorStopped(f"{run.stopped} during {stage} run {name!r} on {cell}; its "
                                  f"record in {folder} {whole}, not counted; the stage's gates were not evaluated")
        if run.recording.failed:  # a disk's fault, not the release's (mid-run or at close)
            raise RecordError(f"the record of {stage} run {name!r} on {cell} could not be written "
                              f"({run.recording.failed}); the run is not counted and the stage's gates were not "
                              f"evaluated; {folder / 'summary.json'} says what ran")
        shadow = run.write_shadow(folder) if plan.shadow else None
        try:
            store.add_run(record_id(folder), cell, stage, bundle.id, name, folder, start.move_seq,
                          runs_key(plan, runs), shadow)
        except ReleaseError as exc:
            raise ReleaseError(f"{stage} run {name!r} on {cell}: its record in {folder} is kept but could not be "
                               f"counted ({exc}); the stage's gates were not evaluated") from None
        folders.append(str(folder))
        if run.operator.count:  # pressed after the run had stopped for a cause of its own: that run is evidence
            raise OperatorStopped(f"{run.operator.reason} during {stage} run {name!r} on {cell}, after it stopped "
                                  f"({run.stopped}); its record in {folder} is counted; no further run was started "
                                  f"and the stage's gates were not evaluated")
    return evaluate_stage(store, plan, cell, stage, folders, start, runs, in_force)


def _calibration(bundle: Bundle) -> str | None:
    """The file a run of ``bundle`` takes as its calibration, looked for again before each run: recalibrated in
    place since the stage started, the release's runs go on from the copy kept beside it."""
    path = calibration_file(bundle)
    return None if path is None else str(path)


def _incumbent(store: Store, cell: str) -> Bundle | None:
    """What drives the cell in shadow mode: production's current release, its pointers checked against the log
    and its inputs against its manifest (None: the taught program). Not its calibration: the robot runs on the
    candidate's (a recalibration since the incumbent was made stopped the pilot of the release made on it)."""
    current, _ = log.check_pointers(store, cell, "production")
    if current is None:
        return None
    incumbent = store.bundle(current)
    verify_bundle(incumbent, calibration=False)
    return incumbent


def _start(make, scenario, bundle: Bundle, incumbent: Bundle | None, shadow: bool):
    """The stage's run, built and checked: what it loaded is still the release, and in shadow mode the incumbent
    that drives is still its own (nothing recorded yet)."""
    run = make(scenario)
    try:
        verify_bundle(bundle, run.policy.candidate if shadow else run.policy, run.cell.profile)
        if incumbent is not None:
            verify_bundle(incumbent, run.policy.incumbent, calibration=False)
    except BundleMismatch:
        run.close()
        raise
    return run


def _claim_folder(store: Store, cell: str, stage: str, name: str) -> Path:
    """A new run folder, made here without exist_ok: of two runs started at once that picked the same number,
    the later one takes the next (neither writes into the other's folder)."""
    parent = make_folder(store.site / "runs" / cell / stage, "--site")
    number = _next_number(store)
    while True:
        folder = parent / f"{number:04d}-{name}"
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            number += 1
        except OSError as exc:
            raise OutputError(f"--site {store.site}: cannot create the run folder {folder} "
                              f"({exc.strerror or exc.__class__.__name__})") from None


def _next_number(store: Store) -> int:
    """The next run folder's number: past every counted run and every folder on disk (a stopped run's folder
    is kept but not counted; numbered from the counted runs alone, the stage's next run met it and was refused)."""
    on_disk = (int(f.name.partition("-")[0]) for f in (store.site / "runs").glob("*/*/*-*")
               if f.name.partition("-")[0].isdigit())
    return max(store.next_run_number(), 1 + max(on_disk, default=0))


def _evidence(store: Store, rows: list[RunRow], kept: Kept) -> tuple[list[RunEvidence], list[str]]:
    """The runs of ``rows`` that read as the records counted (as kept once read, ``kept``), and why each other one
    does not."""
    runs, refused = [], []
    for row in rows:
        try:
            runs.append(counted_run(store, row, kept.read))
        except ReleaseError as exc:
            refused.append(str(exc))
    return runs, refused


def evaluate_stage(store: Store, plan: StagePlan, cell: str, stage: str, folders: list[str] = (),
                   start: Start | None = None, runs: list[dict] | None = None,
                   in_force: StagePlan | None = None) -> StageResult:
    """Evaluate the gates of (cell, stage) on its current release's runs made as ``plan`` makes them since it
    became current (``runs_key``), against last_good's runs there made so. Each run is read from its record once:
    later evaluations take its evidence as kept then (``kept``), so a run costs the same however long the history.

    A counted run that cannot be read as the record counted (gone, damaged, replaced), or that an earlier gates
    entry counted and the runs table no longer holds so, is left out and named in ``refused``: the verdict is
    then never pass, yet it is decided and logged (a failing production release still rolls back, under the plan
    in force), and the stage's next evaluation is not blocked by it. ``start``: what the runs started on (default:
    the stage now); StageError, nothing logged or moved, when the stage moved since. ``runs``: the runs given in
    place of the plan's (``--scenario``), logged by name; such a verdict moves nothing (``acts``). ``in_force``: the
    stage's part of the plan in force (default ``plan``), logged beside ``plan``'s hash: a verdict on another plan
    is logged and moves nothing, a pass there makes no release last_good and a fail rolls nothing back."""
    if start is None:
        moved = log.last_pointer_move(store, cell, stage)
        start = Start(*log.check_pointers(store, cell, stage), moved.seq if moved else 0)
    logged = log.entries(store)
    key, ran, judged_by = _judged_by(plan, runs, in_force)
    under, shadows = log.counted_under(logged), log.counted_shadows(logged)
    kept = Kept(store, logged)
    # or as an older cellguard keyed them, by the whole plan (runs it keyed by the text alone are ``key``, and its
    # whole plan ``ran``, where the plan names no file: a units map's runs then are of no known map)
    same = {key} if runs is not None else {key, log.WHOLE_PLAN + ran}
    every = _bound(store.runs(cell, stage, start.current, start.move_seq), shadows)
    rows = [r for r in every if under.get(r.seq, r.runs) in same]
    taken, refused = _evidence(store, rows, kept)
    refused += _dropped(store, cell, stage, start, every)
    good, good_rows, baseline = [], [], "no last_good on this stage"
    if start.last_good and start.last_good != start.current:
        made = [(r, under.get(r.seq, r.runs)) for r in _bound(store.runs(cell, stage, start.last_good), shadows)]
        good_rows = [r for r, k in made if k in same]
        good, refused_good = _evidence(store, good_rows, kept)
        refused += refused_good
        baseline = f"last_good {start.last_good} has no {'readable ' if good_rows else ''}runs of this stage's runs"
        older = sorted(k[len(log.WHOLE_PLAN):] for _, k in made if k and k.startswith(log.WHOLE_PLAN))
        if older and not good_rows:  # an older cellguard keyed them by the whole plan, gates included
            baseline = (f"last_good {start.last_good}'s runs here were counted by an older cellguard under plan "
                        f"{older[-1][:12]}, comparable only under that whole plan")
    results = tuple(evaluate(g, taken, good, baseline) for g in plan.gates)
    outcome = verdict(results)
    outcome = INCONCLUSIVE if refused and outcome == PASS else outcome
    evidence = [r.record_id for r in taken]
    rolled = None
    with store.transaction():
        _still(store, cell, stage, start, folders)
        signed = kept.keep(taken + good)
        entry = log.append(store, {"kind": "gates", "cell": cell, "stage": stage, "release": start.current,
                                   "verdict": outcome, "gates": [r.to_dict() for r in results],
                                   "evidence": evidence, "last_good_evidence": [r.record_id for r in good],
                                   "refused": refused, "last_good": start.last_good,
                                   "runs": [[r.seq, r.record_id] for r in rows],
                                   "last_good_runs": [[r.seq, r.record_id] for r in good_rows],
                                   log.SHADOWS: log.shadow_refs(rows + good_rows), log.KEPT: signed,
                                   "scenario": [e.get("name", "run") for e in runs or ()],
                                   "plan_sha256": plan_hash(plan), log.PLAN: ran, log.RUNS: key,
                                   log.IN_FORCE: judged_by})
        counted, judged = log.passed(entry.body, entry.body[log.IN_FORCE]), acts(entry.body)
        if counted and start.last_good is None:  # the first release to pass here
            store.set_pointers(cell, stage, start.current, start.current)
        elif judged and outcome == FAIL and stage == "production" and start.last_good not in (None, start.current):
            failing = [r.metric for r in results if r.status == FAIL]
            rolled = rollback(store, cell, stage, reason=f"production gates failed: {', '.join(failing)} (log "
                              f"entry {entry.seq})", automatic=True, gates=[r.to_dict() for r in results],
                              evidence=evidence).body["to"]
    return StageResult(cell, stage, start.current, outcome, results, tuple(evidence), tuple(refused),
                       tuple(folders), rolled, entry.seq, counted, judged)


def acts(body: dict) -> bool:
    """Whether a gates entry's verdict may move a pointer (a pass let its release on, a production fail roll it
    back): only one on the plan's own runs, that plan the stage's part of the plan in force it logged. A pass
    elsewhere never let a release on (``log.passed``), yet a fail under an ad-hoc ``--plan`` (one cycle against a
    1 s cycle time) or on ``--scenario`` runs (a fault) rolled production back."""
    return not body.get("scenario") and log.ran_plan(body, body.get(log.IN_FORCE))


def _judged_by(plan: StagePlan, runs: list[dict] | None, in_force: StagePlan | None) -> tuple[str, str, str]:
    """(``runs_key``, ``plan_key`` of ``plan``, ``plan_key`` of ``in_force``, default ``plan``) of an evaluation: a
    GateError naming a file the runs it makes name that cannot be read (``robot_files``). Of a verdict that cannot
    act (on runs given with ``--scenario``, or on another plan than the one in force) a plan whose file cannot be
    read is ``log.UNREAD``: such a verdict is logged, as before, and judged by no plan."""
    key, ran = runs_key(plan, runs), _key(plan, acts=runs is None)
    return key, ran, ran if in_force is None or in_force is plan else _key(in_force, acts=False)


def _key(plan: StagePlan, acts: bool) -> str:
    """``plan_key`` of ``plan``; ``log.UNREAD`` where a file it names cannot be read and the verdict cannot act."""
    try:
        return plan_key(plan)
    except GateError:
        if acts:
            raise
        return log.UNREAD


def plan_hash(plan: StagePlan) -> str:
    """The stage's plan as written (its runs and gates: the gate's definition), logged beside its results."""
    return hashlib.sha256(canonical_json(plan.model_dump(mode="json"))).hexdigest()


def plan_key(plan: StagePlan) -> str:
    """The stage's plan a pass is judged by (``log.PLAN``, ``log.IN_FORCE``): for a plan naming files, its text as
    written and what they hold (``log.files_key`` of ``plan_hash`` and ``runs_key``): a pass under one units map
    promoted under an edited one. Made of what every gates entry logs, an older cellguard's too, whose pass on it
    still promotes; for a plan naming no file it is ``plan_hash``, as an older cellguard judged it."""
    written = plan_hash(plan)
    return log.files_key(written, runs_key(plan)) if robot_file_paths(plan.runs_beside()) else written


def runs_key(plan: StagePlan, runs: list[dict] | None = None) -> str:
    """What makes a stage's runs, noted on each run's row and logged with its gates (``log.RUNS``), and so the runs
    an evaluation counts: the sha256 of ``plan`` but its gates (its runs, clock, shadow: all that decides how they
    run) with what the files its runs' robots name hold (``plan.robot_files``: runs an older cellguard keyed by
    the text alone, their units unknown, count no more under a plan naming a file), or for ``runs`` given in place
    of its runs (``--scenario``) ``log.SCENARIO`` and that of the plan with those runs. Runs of an ad-hoc plan padded the next
    verdict under the plan in force; keyed by the whole plan, a gate added dropped every run of last_good, and with
    them the rollback; keyed by the text alone, the same plan beside another units map (or that map edited) counted
    runs in other units as its own. An evaluation takes a run as the log's first gates entry counting it says
    (``log.counted_under``), else as its row."""
    made = plan if runs is None else plan.model_copy(update={"runs": runs})
    digest = _with_files(made.model_dump(mode="json", exclude={"gates"}), plan.runs_beside() if runs is None else runs)
    return digest if runs is None else f"{log.SCENARIO}:{digest}"


def _with_files(written: dict, runs: list[dict]) -> str:
    """The sha256 of ``written`` (a plan's dump) with what the files ``runs`` name hold (``robot_files``: a GateError
    naming one that cannot be read), of ``written`` alone where they name none."""
    read = robot_files(runs)
    return hashlib.sha256(canonical_json({**written, "files": read} if read else written)).hexdigest()


def _bound(rows: list[RunRow], shadows: dict[int, str]) -> list[RunRow]:
    """``rows`` each with the shadow hash the log counted it with (``log.counted_shadows``), else its own: a row
    set to the hash of an edited shadow.json reads that file as edited, and the next entry logs the counted hash."""
    return [replace(r, shadow=shadows.get(r.seq, r.shadow)) for r in rows]


def _dropped(store: Store, cell: str, stage: str, start: Start, rows: list[RunRow]) -> list[str]:
    """Each run an earlier gates entry of this release here counted that ``rows`` no longer hold as counted (its
    row deleted, relabelled, or moved before the release came: a failing run gone, the next evaluation passed)."""
    have = {(r.seq, r.record_id) for r in rows}
    return [f"run {seq} (record {rid}), counted by log entry {e.seq}, is no longer among this release's runs here "
            f"(the runs table edited outside cellguard)"
            for e in log.entries(store) if e.seq > start.move_seq and e.body.get("kind") == "gates"
            and (e.body.get("cell"), e.body.get("stage"), e.body.get("release")) == (cell, stage, start.current)
            for seq, rid in e.body.get("runs") or [] if (seq, rid) not in have]


def _still(store: Store, cell: str, stage: str, start: Start, folders) -> None:
    """StageError unless (cell, stage) is, under the write lock, as its runs started (a racing promotion or
    rollback moved it, or another run's first pass set last_good: these gates would act on pointers they did not
    evaluate against)."""
    moved = log.last_pointer_move(store, cell, stage)
    now = Start(*log.check_pointers(store, cell, stage), moved.seq if moved else 0)
    if now != start:
        kept = f"; the records stay in {', '.join(folders)}" if folders else ""
        raise StageError(f"{stage} on {cell}: {_change(store, cell, stage, start, now)} by another command while the "
                         f"runs of {start.current} were going or evaluated: their gates were not logged and nothing "
                         f"moved{kept}; run the stage again")


def _change(store: Store, cell: str, stage: str, start: Start, now: Start) -> str:
    """How (cell, stage) differs from ``start``: the pointers now, which changed from what, and the latest log entry
    that set them. Named as the stage's last move, another run's first pass that made its release last_good read as
    a move of current by the promotion made before either run."""
    was = [f"current was {start.current}" if now.current != start.current else
           f"current left {start.current} and came back" if now.move_seq != start.move_seq else None,
           f"last_good was {start.last_good or 'none'}" if now.last_good != start.last_good else None]
    moved = now.move_seq != start.move_seq
    move = log.last_pointer_move(store, cell, stage) if moved else None  # what moved current, and what set the
    latest = log.last_pointer_change(store, cell, stage)  # pointers last if that is later (a pass after a promotion)
    named = [e for e in (move, latest) if e is not None]
    if len(named) == 2 and move.seq == latest.seq:
        named.pop()
    by = "; ".join(map(_entry_words, named)) or "no log entry sets them"  # the log's last entries deleted meanwhile
    return (f"current {now.current or 'none'}, last_good {now.last_good or 'none'} ({', '.join(filter(None, was))}; "
            f"{by}), {'moved' if moved else 'changed'}")


def _entry_words(entry) -> str:
    """A log entry that set a stage's pointers, as a refusal names it."""
    b = entry.body
    what = {"promote": "a promotion of", "rollback": "a rollback to"}.get(b["kind"])
    return f"log entry {entry.seq}, " + (f"{what} {b['to']}" if what else f"a pass of {b['release']}'s gates")


def _driver(plan: StagePlan, bundle: Bundle, incumbent: Bundle | None) -> tuple[str, dict]:
    """(policy, envelope) of what drives the cell: the release, or in shadow mode the incumbent."""
    if not plan.shadow:
        return bundle.policy_spec, bundle.manifest["envelope"]
    if incumbent is None:
        return INCUMBENT_FALLBACK, {}
    return incumbent.policy_spec, incumbent.manifest["envelope"]


def _maker(plan: StagePlan, bundle: Bundle, incumbent: Bundle | None, context: dict):
    """``make_run(scenario)`` for the stage: the plan's clock, or the shadow run in pilot (simulated time)."""
    if plan.shadow:
        from cellguard.release.shadow import ShadowRun

        context = {**context, "mode": "shadow", "incumbent": incumbent.id if incumbent else INCUMBENT_FALLBACK}

        def make(sc):
            return ShadowRun(sc, bundle.policy_spec, bundle.guard)
    else:
        make = CLOCKS[plan.clock]

    def build(sc):
        run = make(sc)
        run.release = context  # written into the record's context (cellguard.record.session)
        return run

    return build


def status(store: Store) -> list[dict]:
    """Per cell and stage: current, last_good, the latest verdict of current there and, for a pass, why it counts
    for nothing under the plan in force now (``log.not_counted``; ``plan_error``: why that plan does not load)."""
    out = []
    for cell in store.cells():
        in_force, error = in_force_hashes(store, cell)
        for stage in STAGES:
            p = store.pointers(cell, stage)
            ev = last_evaluation(store, cell, stage, p.current) if p.current else None
            out.append({"cell": cell, "stage": stage, "current": p.current, "last_good": p.last_good,
                        "verdict": ev.body["verdict"] if ev else None,
                        "not_counted": log.not_counted(ev.body, in_force.get(stage)) if ev else None,
                        "plan_error": None if stage in in_force else error})
    return out


def in_force_hashes(store: Store, cell: str) -> tuple[dict[str, str], str | None]:
    """(stage -> the key of its part of the plan in force now at ``store``'s site for ``cell``, None), or (the
    stages that have one, why the others do not, naming each): what a pass is judged by, as ``run`` and ``promote``
    judge it. A command that only reads (status, report) still answers when it does not load; a units file one
    stage's runs name, gone, leaves the other stages judged."""
    try:
        plans = plan_in_force(store.site, cell)
    except CellguardError as exc:
        return {}, str(exc)
    keys, errors = {}, []
    for stage, plan in plans.items():
        try:
            keys[stage] = plan_key(plan)
        except CellguardError as exc:
            errors.append(f"stage {stage}: {exc}")
    return keys, "; ".join(errors) or None


def last_good_note(store: Store, entry: log.LogEntry) -> str:
    """Who is last_good at a promotion's stage after ``entry`` and, where the outgoing release was not made so,
    why (``log.Judged``): a pass an older cellguard logged without its plan stopped making its release last_good
    after an upgrade, and nothing said so. A pass on the plan in force as written under files edited since says so,
    as a refusal to promote does (``files_edit``)."""
    b = entry.body
    last_good = store.pointers(b["cell"], b["stage"]).last_good
    outgoing = b.get("from")
    if outgoing is None or outgoing == last_good:
        return f"last_good {last_good or 'none'}"
    try:
        plan = plan_in_force(store.site, b["cell"])[b["stage"]]
        edit = partial(files_edit, plan) if plan_key(plan) == b.get(log.IN_FORCE) else None
    except CellguardError:  # the plan in force unread since: the reason without the files
        edit = None
    why = log.Judged(log.entries(store)).why_not(b["cell"], b["stage"], outgoing, b.get(log.IN_FORCE), edit)
    return f"last_good {last_good or 'none'}, not {outgoing}: {why}"
