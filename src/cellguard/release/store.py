"""The release store: one SQLite file in the site's folder (bundles, pointers, runs, the log).

Per (cell, stage) two pointers, as MLflow's aliases: ``current`` (what runs there now) and
``last_good`` (the last release whose gates passed there). A command's changes (a pointer move
and its log entry) are one transaction: a refused or failed command leaves the store as it was.
"""

from __future__ import annotations

import os
import re
import sqlite3
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from cellguard.output import make_folder
from cellguard.record.json_values import loads
from cellguard.release.bundle import Bundle, canonical_json, release_id
from cellguard.release.errors import ReleaseError

STORE_FILE = "release.sqlite"
LOCK_WAIT_S = 5.0  # how long a command waits for another's write lock before it is refused
STAGES = ("sim", "bench", "pilot", "production")
ADDED_RUN_COLUMNS = ("runs_sha256", "shadow_sha256")  # the runs columns an older cellguard's store lacks

KEPT_TABLE = "kept_evidence"  # each counted run's evidence as read from its record once (``kept``); not in TABLES
KEPT_COLUMNS = ("record_sha256", "body")
KNOWN_SHOWN = 10  # release ids a refusal lists at most (a site keeps hundreds)
TABLES = ("bundles", "pointers", "runs", "log", "meta")  # every store since the first has held them all
_SCHEMA = """
CREATE TABLE IF NOT EXISTS bundles (id TEXT PRIMARY KEY, manifest TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS pointers (cell TEXT, stage TEXT, current TEXT, last_good TEXT, PRIMARY KEY (cell, stage));
CREATE TABLE IF NOT EXISTS runs (seq INTEGER PRIMARY KEY AUTOINCREMENT, record_id TEXT NOT NULL, cell TEXT,
    stage TEXT, release TEXT, name TEXT, folder TEXT, since_log INTEGER, runs_sha256 TEXT, shadow_sha256 TEXT);
CREATE TABLE IF NOT EXISTS log (seq INTEGER PRIMARY KEY, body TEXT NOT NULL, prev_hash TEXT NOT NULL,
    hash TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT);
"""


@dataclass(frozen=True)
class Pointers:
    cell: str
    stage: str
    current: str | None
    last_good: str | None


@dataclass(frozen=True)
class RunRow:
    """One run of a release at a stage: ``record_id`` is the sha256 of its record file (first 16 hex); ``folder``
    is its run folder relative to the site (``runs/<cell>/<stage>/<number>-<name>``); ``runs`` what made it: the
    stage's runs part of its plan (``promotion.runs_key``; None: made by an older cellguard, which noted none);
    ``shadow`` the sha256 of its ``shadow.json`` (None: no shadow run, or one an older cellguard counted without
    it, whose shadow rows are read as found)."""

    seq: int
    record_id: str
    cell: str
    stage: str
    release: str
    name: str
    folder: str
    runs: str | None
    shadow: str | None


def check_stage(stage: str) -> str:
    if stage not in STAGES:
        raise ReleaseError(f"stage {stage!r}: unknown; stages: {' -> '.join(STAGES)}")
    return stage


class Store:
    """The site's release state; ``site`` is its folder (created on first use).

    ``create=False`` for every command but ``release create``: a mistyped ``--site`` is refused instead of
    becoming an empty store that looks like a whole one (a rollback there said "nothing to roll back to"
    and left it). A store file that is a link to nothing (a share not mounted) is refused either way:
    followed, an empty store was made at its target, and every command after read it as the site's."""

    def __init__(self, site: Path, create: bool = True):
        path = Path(site) / STORE_FILE
        if path.is_symlink() and not path.exists():
            raise ReleaseError(f"--site {site}: {STORE_FILE} is a link to {os.readlink(path)}, which is not there "
                               f"(a share not mounted?); nothing read or created")
        if path.exists() and not path.is_file():
            raise ReleaseError(f"--site {site}: {STORE_FILE} is not a file (a folder?); nothing read or created")
        if not create and not path.exists():
            raise ReleaseError(f"--site {site}: no release store there ({STORE_FILE}); release create makes one")
        self.site = make_folder(Path(site), "--site")
        self.log_seen: dict = {}  # each log row as stored -> its entry, as ``log.entries`` last checked it
        try:
            self.db = sqlite3.connect(self.site / STORE_FILE, isolation_level=None, timeout=LOCK_WAIT_S)
            self.db.text_factory = _text
            if not create:
                self._check_whole(site, path)
            self.db.executescript(_SCHEMA)
        except sqlite3.Error as exc:
            raise ReleaseError(f"--site {site}: cannot open the release store ({exc})") from None

    def _check_whole(self, site: Path, path: Path) -> None:
        """A store file without its tables (one cut to 0 bytes by a failed copy or a full disk reads as an empty
        database; one a table was dropped from) is refused, not given a fresh schema: read as a store, it was a whole
        log of 0 entries ("chain verified"), and the next promotion began a new chain beside the old runs; a pointers
        table made again read "no release promoted yet"."""
        tables = {row[0] for row in self.db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        missing = sorted(set(TABLES) - tables)
        if missing:
            self.db.close()
            why = (f"holds no release log ({path.stat().st_size} bytes: cut short by a failed copy or a full disk?)"
                   if not tables else f"lacks its table(s) {', '.join(missing)} (edited outside cellguard?)")
            raise ReleaseError(f"--site {site}: {STORE_FILE} {why}; nothing read or created: restore it from a backup")

    def close(self) -> None:
        self.db.close()

    @contextmanager
    def _faults(self):
        """Any sqlite3.Error inside as ReleaseError naming the store: the lock when another process holds it (a
        sqlite3 shell, a backup) past LOCK_WAIT_S, else the fault (a full disk, a read-only store): one line, never
        a traceback."""
        try:
            yield
        except sqlite3.Error as exc:
            if "locked" in str(exc) or "busy" in str(exc):
                raise ReleaseError(f"--site {self.site}: {STORE_FILE} is locked by another process ({exc}, waited "
                                   f"{LOCK_WAIT_S:g} s; a sqlite3 shell or a backup holding it?): nothing changed, "
                                   f"run it again once it is free") from None
            raise ReleaseError(f"--site {self.site}: cannot write {STORE_FILE} ({exc}); nothing changed") from None

    def write(self, sql: str, args: tuple = ()) -> sqlite3.Cursor:
        """``sql`` executed, a sqlite3.Error as ReleaseError (``_faults``): what every write goes through."""
        with self._faults():
            return self.db.execute(sql, args)

    @contextmanager
    def transaction(self):
        """All or nothing: a CellguardError inside rolls every change back (so does a commit the lock refused). A
        sqlite3.Error anywhere inside (a write, the commit) is rolled back too and becomes a ReleaseError
        (``_faults``), so no write in a transaction can end a command in a traceback."""
        with self._faults():
            self.db.execute("BEGIN IMMEDIATE")
            try:
                yield self
                self.db.execute("COMMIT")
            except BaseException:
                if self.db.in_transaction:
                    self.db.execute("ROLLBACK")
                raise

    # bundles
    def add_bundle(self, bundle: Bundle) -> bool:
        """Keep ``bundle``; False if it was already there (a bundle is never changed)."""
        cur = self.write("INSERT OR IGNORE INTO bundles VALUES (?, ?)",
                         (bundle.id, canonical_json(bundle.manifest).decode()))
        return cur.rowcount == 1

    def bundle(self, release: str) -> Bundle:
        """The one release whose id starts with ``release``, compared literally (no wildcards)."""
        if not re.fullmatch(r"[0-9a-f]+", release):
            raise ReleaseError(f"release {release!r}: not a release id (lowercase hex; a unique prefix is enough)")
        rows = self.db.execute("SELECT id, manifest FROM bundles WHERE substr(id, 1, ?) = ? ORDER BY id",
                               (len(release), release)).fetchall()
        if len(rows) > 1:
            raise ReleaseError(f"release {release!r}: ambiguous, {len(rows)} releases start with it: "
                               f"{', '.join(r[0] for r in rows[:KNOWN_SHOWN])}{' ...' if len(rows) > KNOWN_SHOWN else ''}")
        if not rows:
            known = [r[0] for r in self.db.execute("SELECT id FROM bundles ORDER BY id LIMIT ?", (KNOWN_SHOWN + 1,))]
            more = " ..." if len(known) > KNOWN_SHOWN else ""
            raise ReleaseError(f"release {release!r}: unknown; releases: "
                               f"{', '.join(known[:KNOWN_SHOWN]) + more or 'none (release create)'}")
        return _stored_bundle(*rows[0])

    def edited_bundles(self) -> list[str]:
        """Each bundle whose manifest was edited outside cellguard, in words (what ``release verify`` reports)."""
        problems = []
        for rid, text in self.db.execute("SELECT CAST(id AS TEXT), CAST(manifest AS TEXT) FROM bundles"):
            try:
                _stored_bundle(rid, text)
            except ReleaseError as exc:
                problems.append(str(exc))
        return problems

    def bundle_ids(self) -> set[str]:
        """The id of every bundle stored, edited or not: a release named anywhere else must be one of them."""
        return {r[0] for r in self.db.execute("SELECT CAST(id AS TEXT) FROM bundles")}

    # pointers
    def pointers(self, cell: str, stage: str) -> Pointers:
        row = self.db.execute("SELECT current, last_good FROM pointers WHERE cell=? AND stage=?",
                              (cell, check_stage(stage))).fetchone()
        return Pointers(cell, stage, *(row or (None, None)))

    def all_pointers(self) -> list[Pointers]:
        """Every (cell, stage) row as stored, whatever its stage: what ``release verify`` checks."""
        return [Pointers(*r) for r in self.db.execute("SELECT cell, stage, current, last_good FROM pointers")]

    def set_pointers(self, cell: str, stage: str, current: str | None, last_good: str | None) -> None:
        self.write("INSERT OR REPLACE INTO pointers VALUES (?, ?, ?, ?)", (cell, stage, current, last_good))

    def cells(self) -> list[str]:
        """Every cell with pointers; ReleaseError for a row whose cell or releases are not text (a NULL cell, bytes:
        edited outside cellguard), which ``release status`` could neither show nor name."""
        row = self.db.execute("SELECT cell, stage, current, last_good FROM pointers WHERE typeof(cell) != 'text' "
                              "OR typeof(current) NOT IN ('text', 'null') OR typeof(last_good) NOT IN ('text', 'null')"
                              ).fetchone()
        if row is not None:
            raise ReleaseError(f"the pointers row cell {row[0]!r}, stage {row[1]!r}, current {row[2]!r}, last_good "
                               f"{row[3]!r}: names no cell or release (edited outside cellguard); release verify "
                               f"lists every break")
        return [r[0] for r in self.db.execute("SELECT DISTINCT cell FROM pointers ORDER BY cell")]

    # runs
    def add_run(self, record_id: str, cell: str, stage: str, release: str, name: str, folder: Path,
                since_log: int, runs: str, shadow: str | None = None) -> None:
        """Count the run in ``folder`` (under the site), made by ``runs`` (``promotion.runs_key``), its shadow rows
        the file hashing to ``shadow`` (a pilot run's): kept relative to the site, so the site is read the same from
        any working directory, and a copied site reads its own records. A store an older cellguard made takes the
        columns here, at its first run, not as a command only reads it."""
        with self.transaction():
            have = self._run_table()
            for column in (c for c in ADDED_RUN_COLUMNS if c not in have):
                self.db.execute(f"ALTER TABLE runs ADD COLUMN {column} TEXT")
            self.db.execute("INSERT INTO runs (record_id, cell, stage, release, name, folder, since_log, runs_sha256, "
                            "shadow_sha256) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                            (record_id, cell, stage, release, name, Path(folder).relative_to(self.site).as_posix(),
                             since_log, runs, shadow))

    def run_folder(self, row: RunRow) -> Path:
        """Where ``row``'s run is in this site: ``runs/<cell>/<stage>/`` and the folder's own name (older stores
        hold the folder as the working directory of the day saw it, which names the same run folder)."""
        return self.site / "runs" / row.cell / row.stage / Path(row.folder).name

    def runs(self, cell: str, stage: str, release: str, since_log: int = 0) -> list[RunRow]:
        """Runs of ``release`` at (cell, stage) made after log entry ``since_log``."""
        rows = self.db.execute(f"SELECT {self._run_columns()} FROM runs WHERE cell=? AND stage=? AND release=? AND "
                               f"since_log>=? ORDER BY seq", (cell, stage, release, since_log))
        return [RunRow(*r) for r in rows]

    def run_rows(self) -> dict[int, RunRow]:
        """Every counted run by its seq, as stored: what the log's gates entries are checked against."""
        rows = self.db.execute(f"SELECT {self._run_columns()} FROM runs")
        return {r[0]: RunRow(*r) for r in rows}

    def _run_table(self) -> set[str]:
        """The runs table's columns (a store an older cellguard made lacks some of ``ADDED_RUN_COLUMNS``, until a
        run)."""
        return {r[1] for r in self.db.execute("PRAGMA table_info(runs)")}

    def _run_columns(self) -> str:
        """A ``RunRow``'s columns, NULL for each the table has no column for yet."""
        have = self._run_table()
        return ", ".join(["seq, record_id, cell, stage, release, name, folder"] +
                         [c if c in have else "NULL" for c in ADDED_RUN_COLUMNS])

    # kept evidence (``kept``): made at a run's first evaluation, so a store an older cellguard made has no such table
    def kept_body(self, record_sha256: str) -> str | None:
        """The evidence kept for the record hashing to ``record_sha256``, as stored (None: none kept)."""
        rows = self._kept("SELECT CAST(body AS TEXT) FROM {} WHERE record_sha256=?", (record_sha256,))
        return rows[0][0] if rows else None

    def kept_bodies(self) -> list[tuple[str, str]]:
        """Every (record sha256, body) kept, as stored: what ``release verify`` checks against the log."""
        return self._kept("SELECT CAST(record_sha256 AS TEXT), CAST(body AS TEXT) FROM {}")

    def kept_misshapen(self) -> str | None:
        """Why the kept evidence table is not one cellguard made (its columns), or None (it is, or there is none):
        nothing is kept in it or read from it then (the runs' records are read), and ``release verify`` names it."""
        columns = [row[1] for row in self.db.execute(f"PRAGMA table_info({KEPT_TABLE})")]
        return None if columns in ([], list(KEPT_COLUMNS)) else f"columns {', '.join(map(str, columns))}"

    def keep(self, bodies: dict[str, str]) -> bool:
        """Keep each record sha256's evidence body (inside the caller's transaction, with the entry signing them);
        False, keeping none, where the table is misshapen (``kept_misshapen``: every ``release run`` failed on it).
        Every body no live release can read is dropped (it grew with every run ever counted): one whose record is no
        counted run of a release current or last_good at that run's cell and stage. A release that is neither counts
        its runs again only once promoted there anew; its records are then read, and kept, again."""
        if self.kept_misshapen() is not None:
            return False
        self.write(f"CREATE TABLE IF NOT EXISTS {KEPT_TABLE} ({KEPT_COLUMNS[0]} TEXT PRIMARY KEY, "
                   f"{KEPT_COLUMNS[1]} TEXT NOT NULL)")
        for digest, body in bodies.items():
            self.write(f"INSERT OR REPLACE INTO {KEPT_TABLE} VALUES (?, ?)", (digest, body))
        self.write(f"DELETE FROM {KEPT_TABLE} WHERE substr({KEPT_COLUMNS[0]}, 1, 16) NOT IN (SELECT r.record_id FROM "
                   f"runs r JOIN pointers p ON r.cell = p.cell AND r.stage = p.stage AND r.release IN (p.current, "
                   f"p.last_good))")
        return True

    def _kept(self, sql: str, args: tuple = ()) -> list[tuple]:
        """``sql`` on the kept evidence; none where there is no such table, or one edited out of shape (the runs'
        records are read instead)."""
        try:
            return [] if self.kept_misshapen() else self.db.execute(sql.format(KEPT_TABLE), args).fetchall()
        except sqlite3.Error:
            return []

    def next_run_number(self) -> int:
        return (self.db.execute("SELECT COALESCE(MAX(seq), 0) FROM runs").fetchone()[0]) + 1

    # meta
    def meta(self, key: str) -> str | None:
        row = self.db.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        return row[0] if row else None

    def set_meta(self, key: str, value: str) -> None:
        self.write("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))


def _text(raw: bytes) -> str:
    """A text value as str; bytes that are no UTF-8 (written outside cellguard) read with U+FFFD in their place, so
    the entry or bundle holding them shows as edited (sqlite3 raised, a traceback in verify and status)."""
    return raw.decode("utf-8", "replace")


def _stored_bundle(rid: str, text: str) -> Bundle:
    """The bundle as stored; ReleaseError when its manifest is not a JSON object or no longer hashes to its id
    (edited outside cellguard: never acted on, nor read into a traceback)."""
    try:
        manifest = loads(text)
    except ValueError:
        manifest = None
    if not isinstance(manifest, dict):
        raise ReleaseError(f"release {rid}: its manifest is not a JSON object (edited outside cellguard)")
    if release_id(manifest) != rid:
        raise ReleaseError(f"release {rid}: its manifest hashes to {release_id(manifest)}, not its id "
                           f"(edited outside cellguard)")
    return Bundle(rid, manifest)
