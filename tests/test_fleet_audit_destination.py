"""`fleet audit` names where each entry's rows went: the store (host:port/database, never its password), the
outbox a batch waits in (for the store it waits for), or the place rows were deleted from. It showed none, though
every entry logs it (``--json`` had it); an entry logged without one (by hand, or an older tool) is shown without."""

from __future__ import annotations

import datetime as dt
import json
import re

from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.fleet.audit import AUDIT_FILE, append_audit, append_retention, append_withdrawal
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY = DataPolicy("ta", "s1")
STORE = "127.0.0.1:5432/fleet"


def batch():
    return export_batch([Signature("ta", "s1", TODAY.isoformat(), "friction", 0.8, "arm5", "arm-pick-place",
                                   {"current_rms.elbow": 6.0}, 7, 1)], POLICY, TODAY, key=b"k")


def test_each_entry_names_where_its_rows_went(tmp_path):
    b = batch()
    append_audit(tmp_path, b, "queued", "nowhere")  # no store given
    append_audit(tmp_path, b, "queued", STORE)
    append_audit(tmp_path, b, "held", STORE, reason="the policy exports nothing")
    append_audit(tmp_path, b, "sent", STORE)
    append_retention(tmp_path, POLICY, 3, STORE, before="2025-01-01")
    append_withdrawal(tmp_path, POLICY, 2, str(tmp_path / "lake"))
    with open(tmp_path / AUDIT_FILE, "a") as f:  # an entry logged without a destination
        old = {k: v for k, v in json.loads((tmp_path / AUDIT_FILE).read_text().splitlines()[3]).items()
               if k != "destination"}
        f.write(json.dumps(old) + "\n")
    result = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(tmp_path)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()[1:]
    assert len(lines) == 7, result.stdout
    wheres = [re.search(r" batch=\S*(.*)$", line).group(1) for line in lines]
    assert wheres == [" to=outbox", f" to=outbox for {STORE}", f" to=outbox for {STORE} (the policy exports nothing)",
                      f" to={STORE}", f" from={STORE}", f" from={tmp_path / 'lake'}", ""], wheres
