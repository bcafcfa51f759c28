"""This site's memory of what fixed a cause: ``fixes.json`` beside each diagnosed record.

A site keeps its run folders side by side (``site/run-0001/record.mcap`` ...). Diagnosing one
writes ``fixes.json`` beside its record: per finding and recovery behaviour, the cycles it ran in
and those it fixed. The advice for a record is read from its siblings' files of the same site
(records never diagnosed add nothing: the site learns from the incidents it looked at). A sibling with the
record's own ``record_id`` (a ``record recover`` copy, a backup) is the same incident, never an earlier one; of
several siblings with one ``record_id`` the first by name speaks for it, so no incident counts twice.

A sibling's file is another run's, not this record's business: one that cannot be read, or whose
``record_id`` is not text, is skipped, and so is each row that is not one cellguard writes (a
``scope`` other than this site's, counts that are not 0 <= fixed <= tried < 2**63): a crafted
file neither ends the diagnosis nor speaks for the fleet.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from cellguard.output import keep_output

FIXES_FILE = "fixes.json"
MAX_COUNT = 2**63  # counts are cycles of one record: anything near this is not one cellguard wrote


def save_fixes(folder: Path, context: Mapping, fixes) -> None:
    """Write what fixed each cause in the record in ``folder`` beside it (atomic; not rewritten unchanged)."""
    body = {"record_id": context.get("record_id"), "site": context.get("site"), "fixes": list(fixes)}
    keep_output(Path(folder) / FIXES_FILE, json.dumps(body, indent=1), "fixes")


def site_history(folder: Path, site: str | None, record_id: str | None = None) -> list[dict]:
    """Rows of ``fixes`` from the other records of ``site`` beside ``folder``, each with its ``record``: none of
    ``record_id`` (the record diagnosed, under any folder name), one folder per other record."""
    folder = Path(folder).resolve()
    rows: list[dict] = []
    if site is None or not folder.parent.is_dir():
        return rows
    seen = {record_id} - {None}
    for other in sorted(folder.parent.iterdir()):
        if other == folder or not (other / FIXES_FILE).is_file():
            continue
        try:
            body = json.loads((other / FIXES_FILE).read_text())
        except (OSError, ValueError, RecursionError):  # RecursionError: nested deeper than json can read
            continue
        found = site_rows(body, site, other.name)
        if found and found[0]["record"] not in seen:
            seen.add(found[0]["record"])
            rows += found
    return rows


def site_rows(body: object, site: str, name: str) -> list[dict]:
    """The rows of one sibling's parsed ``fixes.json`` (``body``, any JSON value) for ``site``, each with its
    ``record`` (its ``record_id``, else the folder ``name``); none where it is not a file of that site."""
    if not isinstance(body, dict) or body.get("site") != site or not isinstance(body.get("fixes"), list):
        return []
    record = body.get("record_id")
    if record is not None and not isinstance(record, str):
        return []
    rows = [_row(r) for r in body["fixes"]]
    return [{**r, "record": record or name} for r in rows if r is not None]


def _row(r: object) -> dict | None:
    """The fields advice reads from a row cellguard wrote, or None for any other."""
    if not isinstance(r, dict) or r.get("scope", "site") != "site":
        return None
    cause, recovery, tried, fixed = (r.get(k) for k in ("cause", "recovery", "tried", "fixed"))
    if not (isinstance(cause, str) and isinstance(recovery, str) and type(tried) is int and type(fixed) is int):
        return None
    if not 0 <= fixed <= tried < MAX_COUNT:
        return None
    return {"cause": cause, "recovery": recovery, "tried": tried, "fixed": fixed}
