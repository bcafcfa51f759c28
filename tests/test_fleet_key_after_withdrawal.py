"""The key history after a withdrawal: a site whose key was lost is refused a push while its audit log names any
batch a store took, withdrawn since or not. The log names a store by host, port and database, which two stores can
share (a ``service=`` DSN, defaults from the environment): clearing the batches of the store a withdrawal named let a
second store's be stored twice under new ids. `fleet withdraw` again makes the key; then each finding goes once. The
audit shows where each entry's rows went, never a password."""

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


@pytest.mark.parametrize("history", [
    [("sent", "db"), ("withdrawn", "db")],  # "db" may name the store withdrawn from, or another of that name
    [("sent", "db"), ("sent", "db2"), ("withdrawn", "db"), ("withdrawn", "db2")],
    [("sent", "db"), ("withdrawn", "db2")],
    [("sent", "db"), ("withdrawn", "/srv/lake")],
])
def test_a_withdrawal_logged_before_the_key_was_lost_clears_no_batch(tmp_path, history):
    for status, where in history:
        if status == "sent":
            sent(tmp_path, where)
        else:
            append_withdrawal(tmp_path, POLICY, 2, where)
    with pytest.raises(ConfigError, match=r"batch\(es\) of site s1 went to the store from here without it"):
        check_key_history(tmp_path, POLICY)


def test_another_sites_batches_are_no_reason_to_refuse(tmp_path):
    append_audit(tmp_path, export_batch(sigs("s-other"), DataPolicy("ta", "s-other"), TODAY, key=b"k"), "sent", "db")
    check_key_history(tmp_path, POLICY)


def test_a_key_lost_after_a_withdrawal_is_made_by_withdrawing_again_and_each_finding_goes_once(tmp_path):
    from fleet_server import admin_dsn_or_skip, store_name
    from psycopg.conninfo import conninfo_to_dict

    from cellguard.fleet.store import FleetStore, TenantStore

    store = FleetStore(admin_dsn_or_skip(), store_name("keywdrawn"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    site, policy = tmp_path / "site", tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s1\nexport: signatures\n")
    assert push(sigs(), POLICY, site, TenantStore(dsn), today=TODAY).new_rows == 2
    withdrawn = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(policy), "--store", dsn,
                                         "--site-dir", str(site)])
    assert withdrawn.exit_code == 0, withdrawn.output
    (site / KEY_FILE).unlink()  # lost after the withdrawal: the log cannot tell that this store holds nothing now
    with pytest.raises(ConfigError, match="fleet withdraw"):
        push(sigs(), POLICY, site, TenantStore(dsn), today=TODAY)
    again = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(policy), "--store", dsn,
                                     "--site-dir", str(site)])
    assert again.exit_code == 0 and (site / KEY_FILE).is_file(), again.output
    result = push(sigs(), POLICY, site, TenantStore(dsn), today=TODAY)
    assert (result.new_rows, result.new_key) == (2, None)
    with store.admin() as con:
        assert con.execute("SELECT count(*) FROM fleet.signatures WHERE site_id = 's1'").fetchone()[0] == 2
    audit = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)])  # where each went, no password
    where = TenantStore(dsn).where
    assert f" to={where}" in audit.stdout and f" from={where}" in audit.stdout, audit.stdout
    assert conninfo_to_dict(dsn)["password"] not in audit.stdout
