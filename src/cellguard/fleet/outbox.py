"""The outbox: batches that could not reach the fleet store wait at the site, one file each.

Written beside their target and renamed (a crash leaves a whole file or none), mode 0640 as the
audit log; named by the batch's content hash, so queueing the same batch twice keeps one file.
Removed only after the store has taken the batch; a file that cannot be read is never removed,
only named.

Batches are sent in the order they were queued: a later one replaces an earlier one's rows in the
store (a site's counts of a month), so the order decides what the store keeps. Each file holds its
place in the queue (``queued``), one more than any queued before it, given under a lock on the
outbox folder; never a time, as the site's clock can step back (an older batch written under a fast
clock was sent last and its stale count kept). Files queued before the place was written hold none:
they go first, oldest first by modification time.
"""

from __future__ import annotations

import json
from pathlib import Path

from cellguard.errors import OutputError
from cellguard.fleet.audit import refuse_links
from cellguard.fleet.export import Batch
from cellguard.fleet.signature import SignatureError
from cellguard.output import atomic_file, folder_locked, make_folder
from cellguard.yaml_file import read_bounded

OUTBOX = "outbox"
MAX_BATCH_BYTES = 1 << 28  # [bytes] a queued batch larger is not read (a signature is about 1 kB in one)
FILE_MODE = 0o640  # as the audit log: the site's own data, not for every local user
PLACE = "queued"  # a queued file's place in the queue, beside the batch (not part of its content hash)


class Outbox:
    def __init__(self, site_dir: Path):
        self.folder = Path(site_dir) / OUTBOX

    def put(self, batch: Batch) -> Path:
        """Queue ``batch`` last: one place after every batch queued (the same batch queued again moves there). A link
        at its name is refused: ``atomic_file`` writes through a link, and the site's files stay in its folder."""
        name = f"{OUTBOX}/{batch.batch_id}.json"
        refuse_links(self.folder.parent, name)
        path = self.folder.parent / name
        # a second push waits, so two never take the same place; a filesystem without locks goes unguarded
        with folder_locked(make_folder(self.folder, "outbox"), _refused, unguarded=True):
            place = 1 + max((n for n, _, _ in self._queue()[0]), default=0)
            with atomic_file(path, "outbox", mode=FILE_MODE) as f:
                f.write(json.dumps({**batch.to_dict(), PLACE: place}).encode("utf-8"))
        return path

    def pending(self) -> list[tuple[Path, Batch]]:
        """The queued batches this cellguard can read, oldest first (``read`` also names the others)."""
        return self.read()[0]

    def read(self) -> tuple[list[tuple[Path, Batch]], list[tuple[Path, str]]]:
        """(queued batches, oldest first; files that cannot be read, each with why in one line).

        A file that cannot be read (not JSON, not a batch, a newer cellguard's schema, a link to
        nothing, a FIFO) is never removed: it stays queued for a person, or a newer cellguard, to
        deal with, and the other batches go on without it."""
        queue, unreadable = self._queue()
        return [(p, batch) for _, p, batch in queue], unreadable

    def _queue(self) -> tuple[list[tuple[int, Path, Batch]], list[tuple[Path, str]]]:
        """``read``'s, each batch with its place (0: queued before places were written), in the queue's order."""
        if not self.folder.is_dir():
            return [], []
        queue, unreadable = [], []
        for p in sorted(self.folder.glob("*.json"), key=_age):  # so the placeless keep their order of old
            try:
                raw = json.loads(read_bounded(p, "queued batch", SignatureError, MAX_BATCH_BYTES))
            except SignatureError as exc:
                unreadable.append((p, str(exc).removeprefix(f"{p}: ")))
                continue
            except (ValueError, RecursionError) as exc:  # not JSON (or not UTF-8), or nested past reading
                unreadable.append((p, f"not a batch's JSON ({exc.__class__.__name__})"))
                continue
            try:
                queue.append((_place(raw), p, Batch.from_dict(raw)))
            except SignatureError as exc:
                unreadable.append((p, str(exc)))
        return sorted(queue, key=lambda q: q[0]), unreadable

    def count(self) -> int:
        """Files queued, readable or not."""
        return len(list(self.folder.glob("*.json"))) if self.folder.is_dir() else 0

    def done(self, path: Path) -> None:
        path.unlink(missing_ok=True)


def _refused(doing: str, exc: OSError) -> OutputError:
    return OutputError(f"outbox: cannot {doing} its folder ({exc.strerror or exc})")


def _place(raw: object) -> int:
    """A queued file's place in the queue; 0 for one queued before places were written, SignatureError for one
    that is not a count."""
    place = raw.get(PLACE, 0) if isinstance(raw, dict) else 0
    if isinstance(place, bool) or not isinstance(place, int) or place < 0:
        raise SignatureError(f"batch.{PLACE}: expected its place in the queue (a count), got {place!r}")
    return place


def _age(p: Path) -> tuple[int, str]:
    """Oldest first by modification time (the order of files queued before places were written); a file that
    cannot be stat'ed (a link to nothing) first."""
    try:
        return p.stat().st_mtime_ns, p.name
    except OSError:
        return 0, p.name
