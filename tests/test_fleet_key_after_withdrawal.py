"""The key history counts what a store still holds: a site whose key was lost after it withdrew from the store
(`fleet withdraw`, logged ``withdrawn`` there) has nothing left there to store twice, yet its push was refused as if
the batches sent before the withdrawal were still in it. A batch taken after the withdrawal, or by another store, or
a withdrawal from a lake only, still refuses the push in one line."""

from __future__ import annotations

import datetime as dt

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.fleet.audit import append_audit, append_withdrawal
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import check_key_history, push
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import KEY_FILE

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY = DataPolicy("ta", "s1")


def sigs(site: str = "s1") -> list[Signature]:
    return [Signature("ta", site, TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                      {"current_rms.elbow": 6.0 + i}, 7, 1) for i, cause in enumerate(["friction", "servo"])]


def sent(site_dir, to: str) -> None:
    append_audit(site_dir, export_batch(sigs(), POLICY, TODAY, key=b"lost"), "sent", to)


@pytest.mark.parametrize("history, refused", [
    ([("sent", "db"), ("withdrawn", "db")], False),
    ([("sent", "db"), ("sent", "db2"), ("withdrawn", "db"), ("withdrawn", "db2")], False),
    ([("sent", "db"), ("withdrawn", "db"), ("sent", "db")], True),  # taken since the withdrawal
    ([("sent", "db"), ("withdrawn", "db2")], True),  # withdrawn from another store
    ([("sent", "db"), ("withdrawn", "/srv/lake")], True),  # from a lake only: the store still holds it
])
def test_what_a_withdrawal_took_out_of_a_store_is_no_reason_to_refuse(tmp_path, history, refused):
    for status, where in history:
        if status == "sent":
            sent(tmp_path, where)
        else:
            append_withdrawal(tmp_path, POLICY, 2, where)
    append_withdrawal(tmp_path, DataPolicy("ta", "s-other"), 0, "db")  # another site's withdrawal changes nothing
    if refused:
        with pytest.raises(ConfigError, match=r"1 batch\(es\) of site s1 went to the store from here without it"):
            check_key_history(tmp_path, POLICY)
    else:
        check_key_history(tmp_path, POLICY)


def test_a_key_lost_after_a_withdrawal_pushes_each_finding_once(tmp_path):
    from fleet_server import admin_dsn_or_skip
    from psycopg.conninfo import conninfo_to_dict

    from cellguard.fleet.store import FleetStore, TenantStore

    store = FleetStore(admin_dsn_or_skip(), "cgtest_keywithdrawn")
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    site, policy = tmp_path / "site", tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s1\nexport: signatures\n")
    assert push(sigs(), POLICY, site, TenantStore(dsn), today=TODAY).new_rows == 2
    withdrawn = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(policy), "--store", dsn,
                                         "--site-dir", str(site)])
    assert withdrawn.exit_code == 0, withdrawn.output
    (site / KEY_FILE).unlink()  # lost after the withdrawal: the store holds nothing of the site
    result = push(sigs(), POLICY, site, TenantStore(dsn), today=TODAY)
    assert (result.new_rows, result.new_key) == (2, str(site / KEY_FILE))
    with store.admin() as con:
        assert con.execute("SELECT count(*) FROM fleet.signatures WHERE site_id = 's1'").fetchone()[0] == 2
    audit = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)])  # where each went, no password
    where = TenantStore(dsn).where
    assert f" to={where}" in audit.stdout and f" from={where}" in audit.stdout, audit.stdout
    assert conninfo_to_dict(dsn)["password"] not in audit.stdout
