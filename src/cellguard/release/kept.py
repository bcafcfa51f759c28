"""A counted run's evidence, kept in the store when first read from its record.

A stage's gates count every run of the current release there since it came, and last_good's: read and reduced from
their records at each evaluation, a ``release run`` took longer with every run before it (a 1-cycle run about 60 ms,
an 8-cycle production run with its diagnosis about 0.4 s, each time it was counted). The evidence read (context,
cycles, events, the reductions, ``RunEvidence.once``'s figures) is kept, by the whole sha256 of its record, and
taken in place of the record only while the record file still hashes to it, the body was made by this cellguard
(its version and source, ``_code``) under the same profile limits, and its own sha256 is one a gates entry signed
(``log.KEPT``: each entry signs the bodies it kept, in the same transaction). A body edited in the store is never
read (the record is, and ``release verify`` names the body); a record replaced, gone or damaged is read as before,
with the same checks and errors. The shadow file is read and checked at every evaluation, as before.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

import numpy as np
import scipy

import cellguard
from cellguard import __version__
from cellguard.errors import CellguardError
from cellguard.record.json_values import loads
from cellguard.record.reader import CycleRecord, EventRecord
from cellguard.record.writer import RECORD_FILE
from cellguard.release import log
from cellguard.release.bundle import canonical_json, sha256_file
from cellguard.release.evidence import SHADOW_FILE, RunEvidence, _shadow, load_run
from cellguard.release.reductions import Chunks, LimitTicks
from cellguard.robot.registry import make_cell

FORMAT = 1  # the body's layout; a body of another layout or cellguard version is not read (the record is)


class Kept:
    """The runs an evaluation reads (``read``) and what it keeps of them afterwards (``keep``)."""

    def __init__(self, store, log_entries: list[log.LogEntry]):
        self.store = store
        self.signed = log.kept_signed(log_entries)
        self._limits: dict[str, str] = {}  # cell -> ``_limits_sha256``
        self._read: dict[str, frozenset] = {}  # record sha256 -> the ``once`` figures its kept body held

    def read(self, folder: Path, name: str) -> RunEvidence:
        """The run in ``folder`` from its kept evidence, else from its record (``load_run``)."""
        return self._from_kept(Path(folder), name) or load_run(folder, name)

    def _from_kept(self, folder: Path, name: str) -> RunEvidence | None:
        try:
            whole = sha256_file(folder / RECORD_FILE, "record")
            text = self.store.kept_body(whole)
            if text is None or log.kept_sha256(text) not in self.signed:
                return None
            body = loads(text)
            if (body.get("format"), body.get("cellguard"), body.get("record_sha256")) != (FORMAT, _code(), whole):
                return None
            if body["limits_of"] != self._limits_sha256(body["context"].get("cell")):
                return None
            shadow, shadow_sha256 = _shadow(folder / SHADOW_FILE)
        except (CellguardError, ValueError):  # read from the record, as ever: the same checks and errors
            return None
        self._read[whole] = frozenset(body["derived"])
        return _run(body, name, folder, shadow, shadow_sha256)

    def keep(self, runs: list[RunEvidence]) -> list[str]:
        """Keep each of ``runs`` not kept as it is now (read from its record, or given a figure by ``once`` since),
        inside the caller's transaction; the sha256 of each body kept, for its gates entry to sign (``log.KEPT``)."""
        bodies = {}
        for run in runs:
            whole = run.record_sha256
            if whole is None or whole in bodies or self._read.get(whole) == frozenset(run.derived):
                continue
            try:
                bodies[whole] = _body(run, self._limits_sha256(run.context.get("cell")))
            except CellguardError:  # a cell no longer installed: its record is read each time, as before
                continue
        if not bodies or not self.store.keep(bodies):
            return []
        return sorted(log.kept_sha256(t) for t in bodies.values())

    def _limits_sha256(self, cell) -> str:
        """The sha256 of the limits ``reductions.limit_ticks`` takes from ``cell``'s profile: a body counted its
        ticks outside them, so a profile edited since (a plugin's) makes the record be read again."""
        cell = str(cell)
        if cell not in self._limits:
            p = make_cell(cell).profile
            limits = [list(p.joint_names), p.q_min.tolist(), p.q_max.tolist(), p.array("velocity").tolist()]
            self._limits[cell] = hashlib.sha256(canonical_json(limits)).hexdigest()
        return self._limits[cell]


@functools.cache
def _code() -> str:
    """This cellguard: its version and the sha256 of its source, with numpy's and scipy's versions (the reductions'
    and the diagnosis's arithmetic, its statistics). A version number alone is the same across every change made
    before a release is cut: a body kept by a cellguard that read or judged records differently would be taken as
    this one's."""
    digest = hashlib.sha256()
    root = Path(cellguard.__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return f"{__version__}+{digest.hexdigest()[:16]} numpy {np.__version__} scipy {scipy.__version__}"


def _body(run: RunEvidence, limits_of: str) -> str:
    """``run``'s evidence read from its record, as JSON text (keys in their order: a cycle's features keep theirs;
    floats as ``repr``, NaN included, so each value reads back as it was)."""
    c, lim = run.chunks, run.limits
    worst_t = None if c.worst_seam_t_ns is None else int(c.worst_seam_t_ns)
    return json.dumps({"format": FORMAT, "cellguard": _code(), "record_sha256": run.record_sha256,
                       "limits_of": limits_of, "context": run.context,
                       "cycles": [vars(x) for x in run.cycles], "events": [vars(x) for x in run.events],
                       "chunks": [c.latency_ms.tolist(), int(c.seams), float(c.worst_seam_mrad), worst_t],
                       "limits": [int(lim.count), lim.first_cycle, lim.joint], "derived": run.derived},
                      separators=(",", ":"), ensure_ascii=False)


def _run(body: dict, name: str, folder: Path, shadow, shadow_sha256) -> RunEvidence:
    """The run ``body`` (``_body``) keeps, as ``load_run`` reads it from its record."""
    latency, seams, worst, worst_t = body["chunks"]
    whole = body["record_sha256"]
    run = RunEvidence(whole[:16], name, str(folder), body["context"],
                      tuple(CycleRecord(**x) for x in body["cycles"]), tuple(EventRecord(**x) for x in body["events"]),
                      Chunks(np.asarray(latency, dtype=float), seams, worst, worst_t), LimitTicks(*body["limits"]),
                      shadow, shadow_sha256, whole)
    run.derived.update(body["derived"])
    return run
