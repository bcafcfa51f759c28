"""The promotion log: append-only, hash-chained, so an edited or deleted entry shows.

Each entry's hash is sha256(prev_hash + canonical JSON of its body); the first entry's
prev_hash is 64 zeros. The store keeps the head (last hash and count) beside the log, so a
deleted last entry shows, unless the head was moved back in the same edit: in the same file
nothing can tell that from a log that was never longer. A head kept elsewhere (``verify_log``'s
``expect_head``) does. ``verify_log`` recomputes the chain and names every break, and checks
every stage's pointers against the ones the log's entries set, every bundle's manifest against
its id and every release a pointer, an entry or a run names against the bundles kept. Commands
act only on entries that match their hashes, and append only after the store's head.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime, timezone

from cellguard.record.json_values import loads
from cellguard.release.bundle import canonical_json
from cellguard.release.errors import ReleaseError, StageError

GENESIS = "0" * 64
MOVES = ("promote", "rollback")  # the entries that move a stage's current
IN_FORCE = "plan_in_force_sha256"  # a gates or promote entry's key: the stage's part of the plan in force then
# a gates entry's key: the plan it ran with what the files its runs name held (``promotion.plan_key``), as ``IN_FORCE``
# is; absent in an older cellguard's entries, judged by what they logged (``ran``)
PLAN = "plan_files_sha256"
UNREAD = "unread"  # ``IN_FORCE`` (and ``PLAN``) of a verdict that cannot act, its plan's files not read: no plan's key
RUNS = "runs_sha256"  # a gates entry's key: what made the runs it counted (``promotion.runs_key``), not its gates
SCENARIO = "scenario"  # what runs given with ``release run --scenario`` were made under (``counted_under``)
WHOLE_PLAN = "plan:"  # ``counted_under``'s prefix for runs an entry without ``RUNS`` counted: its whole plan's hash
# a promote entry's key: the outgoing release's latest gates entry there under the plan in force (``Judged.under``),
# passed or not (None: it has none), which decided whether it became last_good; present, the entry took ``Judged``'s
# rule, absent, an older cellguard's (``pointers_by_log``)
OUTGOING = "outgoing_gates"
# a gates entry's key: [seq, sha256] of each run it counted (``runs``, ``last_good_runs``) with a shadow.json, so the
# chain signs its shadow rows as it signs its record (kept in the runs table alone, the table and the file edited
# together passed ``release verify``); absent in an older cellguard's entries, which bind it by the run's row alone.
# A key of its own, not a third element of ``runs``: an older cellguard reads these entries without a traceback
SHADOWS = "shadows_sha256"
# a gates entry's key: the sha256 of each run's evidence body it kept (``kept``), so a body is read in place of its
# record only as a gates entry signed it (kept in the store alone, an edited body, a failed cycle turned success, would
# have turned verdicts unseen); absent in an older cellguard's entries, which kept none
KEPT = "kept_sha256"


@dataclass(frozen=True)
class LogEntry:
    seq: int
    body: dict  # kind, cell, stage, release, from/to, gates, evidence (record ids), reason, at (UTC, display)
    prev_hash: str
    hash: str


def entry_hash(prev_hash: str, body: dict) -> str:
    return hashlib.sha256(prev_hash.encode() + canonical_json(body)).hexdigest()


def append(store, body: dict) -> LogEntry:
    """Append ``body`` (inside the caller's transaction); returns the new entry.

    A move must start where the log has the stage now: a command that read the pointers before
    another command's move committed is refused (StageError, rolled back), never logged with a stale ``from``."""
    if body.get("kind") in MOVES:
        _check_from(store, body)
    body = {**body, "at": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    seq, head = tail(store)
    seq += 1
    digest = entry_hash(head, body)
    store.write("INSERT INTO log VALUES (?, ?, ?, ?)", (seq, canonical_json(body).decode(), head, digest))
    store.set_meta("log_head", digest)
    store.set_meta("log_count", str(seq))
    return LogEntry(seq, body, head, digest)


def tail(store) -> tuple[int, str]:
    """(seq, hash) of the log's last entry, refused unless the store's head says the same: appended after a hand
    edit (a deleted last entry, a count that is no number) the new entry would hide the edit or collide."""
    seq, digest = _last(store)
    kept = (store.meta("log_count") or "0", store.meta("log_head") or GENESIS)
    if kept != (str(seq), digest):
        raise ReleaseError(f"the log ends at entry {seq} ({str(digest)[:12]}), the store's head says entry "
                           f"{kept[0][:20]!r} ({kept[1][:12]}): edited outside cellguard (release verify); "
                           f"nothing moved")
    return seq, digest


def _check_from(store, body: dict) -> None:
    """StageError unless the move's ``from`` is the stage's current as the committed log has it."""
    cell, stage = body.get("cell"), body.get("stage")
    last = last_pointer_move(store, cell, stage)
    now = last.body.get("to") if last else None
    if body.get("from") != now:
        where = f"log entry {last.seq}" if last else "no log entry"
        raise StageError(f"{stage} on {cell}: the log has {now} current ({where}), this command read "
                         f"{body.get('from')}: another command moved it meanwhile (run it again) or the pointers were "
                         f"edited (release verify); nothing moved")


def _rows(store) -> list[tuple]:
    """(seq, body, prev_hash, hash) as text, whatever type a hand edit gave them."""
    return store.db.execute("SELECT seq, CAST(body AS TEXT), CAST(prev_hash AS TEXT), CAST(hash AS TEXT) FROM log "
                            "ORDER BY seq").fetchall()


def _body(text: str) -> dict | None:
    """The entry's body, or None when it is not a JSON object (edited outside cellguard)."""
    try:
        body = loads(text)
    except ValueError:
        return None
    return body if isinstance(body, dict) else None


def entries(store) -> list[LogEntry]:
    """Every entry; ReleaseError naming the first that is not a JSON object, does not match its hash or does not
    follow the entry before it (a command never acts on an edited entry, nor reads a key an edit removed, nor
    on a log with an entry deleted or moved from the middle: each entry alone still matched its own hash).

    An entry this ``store`` read and checked before, still stored exactly as it was then (the same seq, text and
    hashes), is taken as checked: each command read and hashed the whole log three to ten times, a promotion at
    4,000 entries about 0.5 s. Only a new or changed row is parsed and hashed again."""
    out, prev_hash, seen, checked = [], GENESIS, store.log_seen, {}
    for row in _rows(store):
        seq, text, prev, digest = row
        entry = seen.get(row)
        body = entry.body if entry else _body(text)
        if entry is None and (body is None or entry_hash(prev, body) != digest):
            what = "not a JSON object" if body is None else "content does not match its hash"
        elif seq != len(out) + 1 or prev != prev_hash:
            what = f"does not follow entry {len(out)} (an entry before it was deleted or moved)"
        else:
            what = None
        if what is not None:
            raise ReleaseError(f"log entry {seq}: {what} (edited outside cellguard); release verify lists every "
                               f"break; nothing moved")
        checked[row] = entry or LogEntry(seq, body, prev, digest)
        out.append(checked[row])
        prev_hash = digest
    store.log_seen = checked
    return out


def passed(body: dict, in_force: str | None) -> bool:
    """A gates entry that lets its release on (promotion, last_good): a pass on the plan's own runs (a pass on
    runs given with ``release run --scenario`` in place of the plan's is logged, never acted on), that plan the
    stage's part of the plan in force (``ran_plan``)."""
    return (body.get("kind") == "gates" and body.get("verdict") == "pass" and not body.get("scenario")
            and ran_plan(body, in_force))


def ran_plan(body: dict, in_force: str | None) -> bool:
    """The gates entry's runs and gates were ``in_force`` (the key of the stage's part of the plan in force; None:
    no plan checked, as entries logged before it was recorded were acted on). Another plan's pass (``release run
    --plan``, one cycle and ``success_rate min: 0``) defines nothing, and an entry that logged no plan (an older
    cellguard) cannot show it ran this one."""
    return in_force is None or in_force in ran(body)


def ran(body: dict) -> set[str]:
    """Each key the plan a gates entry ran goes by, as ``IN_FORCE`` names plans: its ``PLAN``, else (an older
    cellguard) its ``plan_sha256``, that for a plan naming no file; and ``files_key`` of that and its ``RUNS``, that
    for a plan naming files, which an older cellguard's ``RUNS`` already held (its pass promoted after an upgrade)."""
    written, runs = body.get("plan_sha256"), body.get(RUNS)
    keys = {body.get(PLAN, written)} | ({files_key(written, runs)} if written and runs else set())
    return keys - {None, UNREAD}


def files_key(written: str, runs: str) -> str:
    """The key of a plan naming files (``promotion.plan_key``): of its text as written (``plan_sha256``, its gates
    with it) and what made its runs (``RUNS``: its text but its gates, with what those files hold), both of which
    every gates entry logs, so an entry is judged by what it logged, whichever cellguard logged it."""
    return hashlib.sha256(f"files:{written}:{runs}".encode()).hexdigest()


def not_counted(body: dict, in_force: str | None) -> str | None:
    """Why a gates entry's pass lets nothing on under ``in_force`` (the sha256 of the stage's part of the plan in
    force now; None: that plan does not load, so nothing moves), in a few words; None: it counts (``passed``), or it
    is no pass. ``release status`` and ``release report`` show it beside the verdict, which alone read as a pass
    that counted; judged by the plan in force the entry logged, a pass under a plan edited since read as one."""
    if body.get("verdict") != "pass":
        return None
    if body.get("scenario"):
        return "scenario"
    if in_force is None:
        return "plan in force does not load"
    if passed(body, in_force):
        return None
    if not body.get("plan_sha256"):
        return "no plan logged"
    if IN_FORCE not in body:  # an older cellguard logged no plan in force: an ad-hoc plan or an edit since
        return "plan differs from the one in force"
    return "plan edited since" if body[IN_FORCE] in ran(body) else "other plan"


class Judged:
    """Per (cell, stage, release), its latest gates entry on a plan's own runs (not ``--scenario``'s), by the plan
    it ran: what says whether a release passed a stage under a plan in force. A promotion's last_good and the
    replay of it (``pointers_by_log``) both ask it, entry by entry as the log grew: the latest entry of any plan or
    kind decided, and a pass under a stricter ad-hoc ``--plan`` since took the rollback target away. Promotions
    logged so (without ``OUTGOING``) replay as they were decided (``last``)."""

    ANY = "*"  # the key of the latest entry whatever its plan: for no plan in force (nothing checked)

    def __init__(self, log_entries: list[LogEntry] = ()):
        self._latest: dict[tuple, LogEntry] = {}
        self._last: dict[tuple, dict] = {}
        for entry in log_entries:
            self.add(entry)

    def add(self, entry: LogEntry) -> None:
        b = entry.body
        if b.get("kind") != "gates":
            return
        key = (b.get("cell"), b.get("stage"), b.get("release"))
        self._last[key] = b
        if not b.get("scenario"):
            for plan in (*ran(b), self.ANY):
                self._latest[(*key, plan)] = entry

    def last(self, cell: str, stage: str, release: str | None) -> dict:
        """The body of ``release``'s latest gates entry at (cell, stage) of any plan or kind ({}: none)."""
        return self._last.get((cell, stage, release), {})

    def under(self, cell: str, stage: str, release: str | None, in_force: str | None) -> LogEntry | None:
        """The latest gates entry of ``release`` at (cell, stage) that ran ``in_force`` (None: any plan)."""
        return self._latest.get((cell, stage, release, self.ANY if in_force is None else in_force))

    def why_not(self, cell: str, stage: str, release: str | None, in_force: str | None,
                edit: Callable[[dict], str | None] | None = None) -> str | None:
        """None when ``release``'s latest gates at (cell, stage) under ``in_force`` passed (it may be last_good
        there), else why not, in words; ``edit``: what a file the plan in force names held, for an entry that ran
        that plan as written (``promotion.files_edit``, as a refusal to promote says it), else None."""
        entry = self.under(cell, stage, release, in_force)
        if entry is not None:
            if passed(entry.body, in_force):
                return None
            return f"its gates there under the plan in force ended {entry.body['verdict']} (log entry {entry.seq})"
        latest = self.under(cell, stage, release, None)
        if latest is None:
            return "it has no gates entry there on a plan's own runs"
        b = latest.body
        what = "its pass" if b.get("verdict") == "pass" else f"its gates ({b.get('verdict')})"
        if not b.get("plan_sha256"):
            return f"{what} there logged no plan (an older cellguard; log entry {latest.seq})"
        edited = edit(b) if edit else None
        if edited:
            return f"{what} there ran this plan as written, but {edited} (log entry {latest.seq})"
        return (f"{what} there ran another plan ({b.get(PLAN, b['plan_sha256'])[:12]}, log entry {latest.seq}; the "
                f"plan in force has {in_force[:12]})")


def counted_under(log_entries: list[LogEntry]) -> dict[int, str | None]:
    """Each run a gates entry counted (its ``runs``) -> what made it, by the first entry that counted it: that
    entry's ``RUNS``, ``SCENARIO`` for runs given with ``--scenario``; for an entry that logged only its whole plan
    (``plan_sha256``: an older cellguard) ``WHOLE_PLAN`` and that hash, None where it logged neither. The log decides
    over the run's own row, which an edit could relabel."""
    out: dict[int, str | None] = {}
    for e in log_entries:
        b = e.body
        if b.get("kind") == "gates":
            whole = WHOLE_PLAN + b["plan_sha256"] if b.get("plan_sha256") else None
            under = SCENARIO if b.get("scenario") else b.get(RUNS, whole)
            for seq, _ in b.get("runs") or []:
                out.setdefault(seq, under)
    return out


def shadow_refs(rows) -> list[list]:
    """``SHADOWS`` of a gates entry counting ``rows`` (``store.RunRow``): [seq, sha256] of each that has one."""
    return [[r.seq, r.shadow] for r in rows if r.shadow]


def counted_shadows(log_entries: list[LogEntry]) -> dict[int, str]:
    """Each run a gates entry logged a shadow hash for -> that hash, by the first entry that did: the shadow rows
    the run is evidence with, whatever its row says now (an edit could set it to an edited file's hash)."""
    out: dict[int, str] = {}
    for e in log_entries:
        if e.body.get("kind") == "gates":
            for seq, shadow in e.body.get(SHADOWS) or []:
                out.setdefault(seq, shadow)
    return out


def kept_sha256(body_text: str) -> str:
    """The sha256 a gates entry signs a kept evidence body by (``KEPT``)."""
    return hashlib.sha256(body_text.encode()).hexdigest()


def kept_signed(log_entries: list[LogEntry]) -> set[str]:
    """The sha256 of every evidence body a gates entry kept (``KEPT``): the only bodies read in place of records."""
    return {h for e in log_entries if e.body.get("kind") == "gates" for h in e.body.get(KEPT) or []}


def kept_problems(store, log_entries: list[LogEntry]) -> list[str]:
    """Each evidence body kept in the store that no gates entry signed (edited outside cellguard: never read, its
    record is read instead), in words."""
    misshapen = store.kept_misshapen()
    if misshapen is not None:
        return [f"the kept evidence table is not one cellguard made ({misshapen}; edited outside cellguard): "
                f"nothing is kept in it or read from it, the runs' records are read"]
    signed = kept_signed(log_entries)
    return [f"the evidence kept for record {str(digest)[:16]} is not the one a gates entry kept (edited outside "
            f"cellguard; its record is read instead)"
            for digest, text in store.kept_bodies()
            if kept_sha256(str(text)) not in signed or _kept_for(str(text)) != digest]


def _kept_for(body_text: str):
    """The record sha256 a kept body says it was read from (a signed body put under another record's key is named)."""
    try:
        return json.loads(body_text).get("record_sha256")
    except (ValueError, AttributeError):
        return None


def check_pointers(store, cell: str, stage: str) -> tuple:
    """(current, last_good) of (cell, stage) as stored; ReleaseError unless the log's entries set them so (a
    pointer edited outside cellguard would run, promote or roll back a release no gate let there)."""
    p = store.pointers(cell, stage)
    have, want = (p.current, p.last_good), pointers_by_log(entries(store)).get((cell, stage), (None, None))
    if have != want:
        raise ReleaseError(f"{_pointer_break(cell, stage, have, want)}: edited outside cellguard (release verify); "
                           f"nothing moved, nothing run")
    return have


def _pointer_break(cell: str, stage: str, have: tuple, want: tuple) -> str:
    """Stored pointers (current, last_good) that are not what the log set, in words."""
    return (f"pointers of {stage} on {cell}: current {have[0]}, last_good {have[1]}; the log says current "
            f"{want[0]}, last_good {want[1]}")


def run_problems(store, log_entries: list[LogEntry]) -> list[str]:
    """Each run a gates entry counted (``runs``, ``last_good_runs``: [seq, record id]; ``SHADOWS``) that the store's
    runs no longer hold as counted (deleted, its record, release or shadow file's hash relabelled), in words; empty
    when all are there."""
    rows, problems = store.run_rows(), []
    for e in log_entries:
        b = e.body
        shadows = dict(b.get(SHADOWS) or [])
        for key, release in (("runs", b.get("release")), ("last_good_runs", b.get("last_good"))):
            for seq, rid in b.get(key) or []:
                row, shadow = rows.get(seq), shadows.get(seq)
                have = (row.record_id, row.cell, row.stage, row.release) if row else None
                if have != (rid, b.get("cell"), b.get("stage"), release):
                    now = "is gone" if row is None else (f"now holds record {row.record_id} of release {row.release} "
                                                         f"at {row.stage} on {row.cell}")
                elif shadow is not None and row.shadow != shadow:
                    now = (f"now holds shadow file hash {(row.shadow or 'none')[:16]}, not {shadow[:16]} counted "
                           f"with it")
                else:
                    continue
                problems.append(f"run {seq} (record {rid} of release {release}), counted by log entry {e.seq}, "
                                f"{now} (the runs table edited outside cellguard)")
    return problems


def size(store) -> int:
    """How many entries the log holds, readable or not."""
    return store.db.execute("SELECT COUNT(*) FROM log").fetchone()[0]


def last_pointer_move(store, cell: str, stage: str) -> LogEntry | None:
    """The latest entry that moved (cell, stage)'s ``current``: what the next run there records."""
    for entry in reversed(entries(store)):
        b = entry.body
        if b.get("cell") == cell and b.get("stage") == stage and b.get("kind") in MOVES:
            return entry
    return None


def pointers_by_log(log_entries: list[LogEntry]) -> dict[tuple, tuple]:
    """(cell, stage) -> (current, last_good) as the entries set them (``pointer_changes``)."""
    return {key: after for _, key, after in pointer_changes(log_entries)}


def pointer_changes(log_entries: list[LogEntry]) -> Iterator[tuple[LogEntry, tuple, tuple]]:
    """Each entry that set a stage's pointers, as (entry, (cell, stage), (current, last_good) it set), by
    promotion.py's rules: a promotion makes the outgoing release last_good if its latest gates there under the plan
    in force the promotion logged passed (``Judged``), the first release to pass a stage under the plan in force its
    gates entry logged is its own last_good, a rollback makes last_good current. Each entry names the plan in force
    when it acted (``IN_FORCE``), so the replay needs no plan file, and a plan edited since leaves the pointers as
    they were set."""
    state, judged = {}, Judged()
    for e in log_entries:
        b = e.body
        key = (b.get("cell"), b.get("stage"))
        current, last_good = state.get(key, (None, None))
        if b.get("kind") == "gates":
            judged.add(e)
            if last_good is not None or not passed(b, b.get(IN_FORCE)):
                continue
            after = (current, current)
        elif b.get("kind") == "promote":
            outgoing = b.get("from")
            if OUTGOING in b:
                kept = outgoing is not None and judged.why_not(*key, outgoing, b.get(IN_FORCE)) is None
            else:  # logged by an older cellguard, which took the outgoing release's latest gates there
                kept = passed(judged.last(*key, outgoing), b.get(IN_FORCE))
            after = (b.get("to"), outgoing if kept else last_good)
        elif b.get("kind") == "rollback":
            after = (b.get("to"), b.get("to"))
        else:
            continue
        state[key] = after
        yield e, key, after


def last_pointer_change(store, cell: str, stage: str) -> LogEntry | None:
    """The latest entry that set (cell, stage)'s pointers (``pointer_changes``), moving ``current`` or not: a run's
    gates that made their release last_good changed the stage for a run going there as a promotion does."""
    changes = [e for e, key, _ in pointer_changes(entries(store)) if key == (cell, stage)]
    return changes[-1] if changes else None


def _last(store) -> tuple[int, str]:
    """(seq, hash) of the log's last entry; (0, GENESIS) when it is empty."""
    return store.db.execute("SELECT seq, CAST(hash AS TEXT) FROM log ORDER BY seq DESC LIMIT 1").fetchone() or (
        0, GENESIS)


def head(store) -> str:
    """The hash of the log's last entry: kept outside the store, it is ``verify_log``'s ``expect_head`` later."""
    return _last(store)[1]


def verify_log(store, expect_head: str | None = None) -> list[str]:
    """Every break in the chain, every pointer the log does not account for, every edited bundle and every release
    named without one, in words; empty when whole. ``expect_head``: a head kept elsewhere (a hash or a prefix of
    one); the log must still hold that entry, which finds last entries deleted together with the store's head."""
    if expect_head is not None and not re.fullmatch(r"[0-9a-f]{12,64}", expect_head):
        raise ReleaseError(f"--expect-head {expect_head[:80]!r}: not a hash (12 to 64 lowercase hex characters)")
    problems, prev, expected_seq, readable, hashes = [], GENESIS, 1, [], []
    for seq, text, prev_hash, digest in _rows(store):
        hashes.append(digest)
        if seq != expected_seq:
            problems.append(f"entries {expected_seq}..{seq - 1} missing (deleted)")
        if prev_hash != prev:
            problems.append(f"entry {seq}: previous hash {prev_hash[:12]} does not match entry before it "
                            f"({prev[:12]}): an entry before it was deleted or edited")
        body = _body(text)
        if body is None:
            problems.append(f"entry {seq}: not a JSON object (edited)")
        else:
            readable.append(LogEntry(seq, body, prev_hash, digest))
            if entry_hash(prev_hash, body) != digest:
                problems.append(f"entry {seq}: content does not match its hash (edited)")
        prev, expected_seq = digest, seq + 1
    count = store.meta("log_count") or "0"
    if str(expected_seq - 1) != count or prev != (store.meta("log_head") or GENESIS):
        problems.append(f"log ends at entry {expected_seq - 1} with hash {prev[:12]}, the store's head says entry "
                        f"{count} ({(store.meta('log_head') or GENESIS)[:12]}): the last entries were deleted")
    if expect_head is not None and not any(str(h).startswith(expect_head) for h in hashes):
        problems.append(f"no entry has the expected head {expect_head}: it was deleted or rewritten, and the "
                        f"store's head with it")
    by_log = pointers_by_log(readable)
    stored = {(p.cell, p.stage): (p.current, p.last_good) for p in store.all_pointers()}
    for cell, stage in sorted(by_log.keys() | stored.keys(), key=str):
        have, want = stored.get((cell, stage), (None, None)), by_log.get((cell, stage), (None, None))
        if have != want:
            problems.append(f"{_pointer_break(cell, stage, have, want)} (edited outside cellguard)")
    whole = [e for e in readable if entry_hash(e.prev_hash, e.body) == e.hash]  # an edited one is named above
    return (problems + run_problems(store, whole) + kept_problems(store, whole) + store.edited_bundles()
            + missing_bundles(store, whole))


def missing_bundles(store, log_entries: list[LogEntry]) -> list[str]:
    """Each release a pointer, a log entry or a counted run names that has no bundle (deleted outside cellguard:
    it can be neither run nor promoted again, and nothing else says it is gone), in words, with what names it."""
    named: dict[str, list[str]] = {}
    for p in store.all_pointers():
        for key in ("current", "last_good"):
            named.setdefault(getattr(p, key), []).append(f"{key} of {p.stage} on {p.cell}")
    for e in log_entries:
        for rid in {e.body.get(k) for k in ("release", "from", "to", "last_good")}:
            named.setdefault(rid, []).append(f"log entry {e.seq}")
    for seq, row in store.run_rows().items():
        named.setdefault(row.release, []).append(f"run {seq}")
    bundles = store.bundle_ids()
    return [f"release {rid}: no bundle (deleted outside cellguard); named by {', '.join(where)}"
            for rid, where in named.items() if rid is not None and rid not in bundles]
