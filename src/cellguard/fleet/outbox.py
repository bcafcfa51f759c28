"""The outbox: batches that could not reach the fleet store wait at the site, one file each.

Written beside their target and renamed (a crash leaves a whole file or none); named by the
batch's content hash, so queueing the same batch twice keeps one file. Removed only after the
store has taken the batch.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from cellguard.errors import OutputError
from cellguard.fleet.export import Batch
from cellguard.fleet.signature import SignatureError

OUTBOX = "outbox"


class Outbox:
    def __init__(self, site_dir: Path):
        self.folder = Path(site_dir) / OUTBOX

    def put(self, batch: Batch) -> Path:
        path = self.folder / f"{batch.batch_id}.json"
        tmp = path.with_suffix(".json.tmp")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with open(tmp, "w") as f:
                json.dump(batch.to_dict(), f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except OSError as exc:
            raise OutputError(f"outbox {path}: cannot write ({exc.strerror or exc.__class__.__name__})") from None
        return path

    def pending(self) -> list[tuple[Path, Batch]]:
        """Queued batches, oldest first. One this cellguard cannot read (queued by a newer one)
        raises SignatureError naming the file, which stays queued."""
        if not self.folder.is_dir():
            return []
        files = sorted(self.folder.glob("*.json"), key=lambda p: (p.stat().st_mtime_ns, p.name))
        out = []
        for p in files:
            try:
                out.append((p, Batch.from_dict(json.loads(p.read_text()))))
            except SignatureError as exc:
                raise SignatureError(f"{p}: {exc}; it stays queued") from None
        return out

    def done(self, path: Path) -> None:
        path.unlink(missing_ok=True)
