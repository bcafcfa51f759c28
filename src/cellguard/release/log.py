"""The promotion log: append-only, hash-chained, so an edited or deleted entry shows.

Each entry's hash is sha256(prev_hash + canonical JSON of its body); the first entry's
prev_hash is 64 zeros. The store keeps the head (last hash and count) beside the log, so a
deleted last entry shows too. ``verify_log`` recomputes the chain and names the first break,
and checks every stage's pointers against the ones the log's entries set.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from datetime import datetime, timezone

from cellguard.release.bundle import canonical_json
from cellguard.release.errors import ReleaseError, StageError

GENESIS = "0" * 64
MOVES = ("promote", "rollback")  # the entries that move a stage's current


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
    head = store.meta("log_head") or GENESIS
    seq = int(store.meta("log_count") or 0) + 1
    digest = entry_hash(head, body)
    store.db.execute("INSERT INTO log VALUES (?, ?, ?, ?)", (seq, canonical_json(body).decode(), head, digest))
    store.set_meta("log_head", digest)
    store.set_meta("log_count", str(seq))
    return LogEntry(seq, body, head, digest)


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
        body = json.loads(text)
    except ValueError:
        return None
    return body if isinstance(body, dict) else None


def entries(store) -> list[LogEntry]:
    """Every entry; ReleaseError naming the first whose body is not a JSON object."""
    out = []
    for seq, text, prev, digest in _rows(store):
        body = _body(text)
        if body is None:
            raise ReleaseError(f"log entry {seq}: not a JSON object (edited outside cellguard); release verify "
                               f"lists every break")
        out.append(LogEntry(seq, body, prev, digest))
    return out


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
    """(cell, stage) -> (current, last_good) as the entries set them, by promotion.py's rules: a promotion
    makes the outgoing release last_good if its latest gates there passed, the first release to pass a
    stage is its own last_good, a rollback makes last_good current."""
    state, passed = {}, {}
    for e in log_entries:
        b = e.body
        key = (b.get("cell"), b.get("stage"))
        current, last_good = state.get(key, (None, None))
        if b.get("kind") == "gates":
            passed[(*key, b.get("release"))] = b.get("verdict") == "pass"
            if b.get("verdict") == "pass" and last_good is None:
                state[key] = (current, current)
        elif b.get("kind") == "promote":
            state[key] = (b.get("to"), b.get("from") if passed.get((*key, b.get("from"))) else last_good)
        elif b.get("kind") == "rollback":
            state[key] = (b.get("to"), b.get("to"))
    return state


def verify_log(store) -> list[str]:
    """Every break in the chain and every pointer the log does not account for, in words; empty when whole."""
    problems, prev, expected_seq, readable = [], GENESIS, 1, []
    for seq, text, prev_hash, digest in _rows(store):
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
    by_log = pointers_by_log(readable)
    stored = {(p.cell, p.stage): (p.current, p.last_good) for p in store.all_pointers()}
    for cell, stage in sorted(by_log.keys() | stored.keys(), key=str):
        have, want = stored.get((cell, stage), (None, None)), by_log.get((cell, stage), (None, None))
        if have != want:
            problems.append(f"pointers of {stage} on {cell}: current {have[0]}, last_good {have[1]}; the log says "
                            f"current {want[0]}, last_good {want[1]} (edited outside cellguard)")
    return problems
