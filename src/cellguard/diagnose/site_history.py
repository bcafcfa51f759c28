"""This site's memory of what fixed a cause: ``fixes.json`` beside each diagnosed record.

A site keeps its run folders side by side (``site/run-0001/record.mcap`` ...). Diagnosing one
writes ``fixes.json`` beside its record: per finding and recovery behaviour, the cycles it ran in
and those it fixed. The advice for a record is read from its siblings' files of the same site
(records never diagnosed add nothing: the site learns from the incidents it looked at).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from cellguard.output import keep_output

FIXES_FILE = "fixes.json"


def save_fixes(folder: Path, context: Mapping, fixes) -> None:
    """Write what fixed each cause in the record in ``folder`` beside it (atomic; not rewritten unchanged)."""
    body = {"record_id": context.get("record_id"), "site": context.get("site"), "fixes": list(fixes)}
    keep_output(Path(folder) / FIXES_FILE, json.dumps(body, indent=1), "fixes")


def site_history(folder: Path, site: str | None) -> list[dict]:
    """Rows of ``fixes`` from the other records of ``site`` beside ``folder``, each with its ``record``.
    A sibling file that cannot be read is skipped (it is not this record's business)."""
    folder = Path(folder).resolve()
    rows: list[dict] = []
    if site is None or not folder.parent.is_dir():
        return rows
    for other in sorted(folder.parent.iterdir()):
        if other == folder or not (other / FIXES_FILE).is_file():
            continue
        try:
            body = json.loads((other / FIXES_FILE).read_text())
        except (OSError, ValueError):
            continue
        if isinstance(body, dict) and body.get("site") == site and isinstance(body.get("fixes"), list):
            rows += [{**r, "record": body.get("record_id") or other.name} for r in body["fixes"] if _row(r)]
    return rows


def _row(r) -> bool:
    return (isinstance(r, dict) and isinstance(r.get("cause"), str) and isinstance(r.get("recovery"), str)
            and isinstance(r.get("tried"), int) and isinstance(r.get("fixed"), int))
