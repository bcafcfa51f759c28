"""The site's audit log: one JSON line per export (what, when, how many rows, which policy version).

Append-only at the site, never sent. A line is written whole (one ``write`` of an ``O_APPEND``
file, then fsync), so a crash leaves every earlier line intact.
"""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path

from cellguard.errors import OutputError
from cellguard.fleet.export import Batch

AUDIT_FILE = "audit.jsonl"


def append_audit(site_dir: Path, batch: Batch, status: str, destination: str) -> dict:
    """Append the export of ``batch`` (``status``: sent, queued, duplicate, nothing) to the log."""
    entry = {"when_utc": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
             "what": batch.export, "rows": batch.rows, "withheld_rows": batch.withheld_rows,
             "policy_version": batch.policy_version, "batch_id": batch.batch_id,
             "tenant_id": batch.tenant_id, "site_id": batch.site_id, "status": status, "destination": destination}
    path = Path(site_dir) / AUDIT_FILE
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o640)
        try:
            os.write(fd, (json.dumps(entry, sort_keys=True) + "\n").encode())
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        raise OutputError(f"audit log {path}: cannot append ({exc.strerror or exc.__class__.__name__})") from None
    return entry


def read_audit(site_dir: Path) -> list[dict]:
    path = Path(site_dir) / AUDIT_FILE
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
