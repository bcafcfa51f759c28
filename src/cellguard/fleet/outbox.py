"""The outbox: batches that could not reach the fleet store wait at the site, one file each.

Written beside their target and renamed (a crash leaves a whole file or none), mode 0640 as the
audit log; named by the batch's content hash, so queueing the same batch twice keeps one file.
Removed only after the store has taken the batch; a file that cannot be read is never removed,
only named.
"""

from __future__ import annotations

import json
from pathlib import Path

from cellguard.fleet.export import Batch
from cellguard.fleet.signature import SignatureError
from cellguard.output import atomic_file
from cellguard.yaml_file import read_bounded

OUTBOX = "outbox"
MAX_BATCH_BYTES = 1 << 28  # [bytes] a queued batch larger is not read (a signature is about 1 kB in one)
FILE_MODE = 0o640  # as the audit log: the site's own data, not for every local user


class Outbox:
    def __init__(self, site_dir: Path):
        self.folder = Path(site_dir) / OUTBOX

    def put(self, batch: Batch) -> Path:
        path = self.folder / f"{batch.batch_id}.json"
        with atomic_file(path, "outbox", mode=FILE_MODE) as f:
            f.write(json.dumps(batch.to_dict()).encode("utf-8"))
        return path

    def pending(self) -> list[tuple[Path, Batch]]:
        """The queued batches this cellguard can read, oldest first (``read`` also names the others)."""
        return self.read()[0]

    def read(self) -> tuple[list[tuple[Path, Batch]], list[tuple[Path, str]]]:
        """(queued batches, oldest first; files that cannot be read, each with why in one line).

        A file that cannot be read (not JSON, not a batch, a newer cellguard's schema, a link to
        nothing, a FIFO) is never removed: it stays queued for a person, or a newer cellguard, to
        deal with, and the other batches go on without it."""
        if not self.folder.is_dir():
            return [], []
        batches, unreadable = [], []
        for p in sorted(self.folder.glob("*.json"), key=_age):
            try:
                raw = json.loads(read_bounded(p, "queued batch", SignatureError, MAX_BATCH_BYTES))
            except SignatureError as exc:
                unreadable.append((p, str(exc).removeprefix(f"{p}: ")))
                continue
            except (ValueError, RecursionError) as exc:  # not JSON (or not UTF-8), or nested past reading
                unreadable.append((p, f"not a batch's JSON ({exc.__class__.__name__})"))
                continue
            try:
                batches.append((p, Batch.from_dict(raw)))
            except SignatureError as exc:
                unreadable.append((p, str(exc)))
        return batches, unreadable

    def count(self) -> int:
        """Files queued, readable or not."""
        return len(list(self.folder.glob("*.json"))) if self.folder.is_dir() else 0

    def done(self, path: Path) -> None:
        path.unlink(missing_ok=True)


def _age(p: Path) -> tuple[int, str]:
    """Oldest first by modification time; a file that cannot be stat'ed (a link to nothing) first."""
    try:
        return p.stat().st_mtime_ns, p.name
    except OSError:
        return 0, p.name
