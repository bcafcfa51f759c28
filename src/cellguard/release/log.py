"""The promotion log: append-only, hash-chained, so an edited or deleted entry shows.

Each entry's hash is sha256(prev_hash + canonical JSON of its body); the first entry's
prev_hash is 64 zeros. The store keeps the head (last hash and count) beside the log, so a
deleted last entry shows too. ``verify_log`` recomputes the chain and names the first break.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from datetime import datetime, timezone

from cellguard.release.bundle import canonical_json

GENESIS = "0" * 64


@dataclass(frozen=True)
class LogEntry:
    seq: int
    body: dict  # kind, cell, stage, release, from/to, gates, evidence (record ids), reason, at (UTC, display)
    prev_hash: str
    hash: str


def entry_hash(prev_hash: str, body: dict) -> str:
    return hashlib.sha256(prev_hash.encode() + canonical_json(body)).hexdigest()


def append(store, body: dict) -> LogEntry:
    """Append ``body`` (inside the caller's transaction); returns the new entry."""
    body = {**body, "at": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    head = store.meta("log_head") or GENESIS
    seq = int(store.meta("log_count") or 0) + 1
    digest = entry_hash(head, body)
    store.db.execute("INSERT INTO log VALUES (?, ?, ?, ?)", (seq, canonical_json(body).decode(), head, digest))
    store.set_meta("log_head", digest)
    store.set_meta("log_count", str(seq))
    return LogEntry(seq, body, head, digest)


def entries(store) -> list[LogEntry]:
    rows = store.db.execute("SELECT seq, body, prev_hash, hash FROM log ORDER BY seq")
    return [LogEntry(seq, json.loads(body), prev, digest) for seq, body, prev, digest in rows]


def last_pointer_move(store, cell: str, stage: str) -> LogEntry | None:
    """The latest entry that moved (cell, stage)'s ``current``: what the next run there records."""
    for entry in reversed(entries(store)):
        b = entry.body
        if b.get("cell") == cell and b.get("stage") == stage and b.get("kind") in ("promote", "rollback"):
            return entry
    return None


def verify_log(store) -> list[str]:
    """Every break in the chain, in words; empty when the log is whole."""
    problems, prev, expected_seq = [], GENESIS, 1
    for e in entries(store):
        if e.seq != expected_seq:
            problems.append(f"entries {expected_seq}..{e.seq - 1} missing (deleted)")
        if e.prev_hash != prev:
            problems.append(f"entry {e.seq}: previous hash {e.prev_hash[:12]} does not match entry before it "
                            f"({prev[:12]}): an entry before it was deleted or edited")
        if entry_hash(e.prev_hash, e.body) != e.hash:
            problems.append(f"entry {e.seq}: content does not match its hash (edited)")
        prev, expected_seq = e.hash, e.seq + 1
    count = int(store.meta("log_count") or 0)
    if expected_seq - 1 != count or prev != (store.meta("log_head") or GENESIS):
        problems.append(f"log ends at entry {expected_seq - 1} with hash {prev[:12]}, the store's head says entry "
                        f"{count} ({(store.meta('log_head') or GENESIS)[:12]}): the last entries were deleted")
    return problems
