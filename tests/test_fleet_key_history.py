"""A site folder whose audit log says batches went to the store before it had a site key (sent by the version
before the key, or under a key since lost): a push made a new key and stored every finding a second time under new
ids, noting only "a new site key". It is refused in one line naming `fleet withdraw`, which deletes what the site
pooled and makes the key; the push after it stores each finding once."""

from __future__ import annotations

import datetime as dt

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.fleet.audit import AUDIT_FILE, append_audit
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import check_key_history, push
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import KEY_FILE
from cellguard.fleet.store import FleetStore, TenantStore

TODAY = dt.datetime.now(dt.timezone.utc).date()
OLD_IDS = b"unkeyed"  # what the version before the key hashed ids with, as far as a test needs


def sigs(tenant: str, site: str) -> list[Signature]:
    return [Signature(tenant, site, TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                      {"current_rms.elbow": 6.0 + i}, 7, 1, "pv-1", "cal-1", "0.1.0")
            for i, cause in enumerate(["friction", "fixture_shift"])]


def sent_before_the_key(site_dir, policy: DataPolicy, status: str = "sent") -> None:
    """An audit log as the version before the key left it: a batch the store took, and no site.key."""
    batch = export_batch(sigs(policy.tenant, policy.site), policy, TODAY, key=OLD_IDS)
    append_audit(site_dir, batch, "queued", "db")
    append_audit(site_dir, batch, status, "db", policy_in_force=policy.version)


@pytest.mark.parametrize("status", ["sent", "duplicate"])
def test_a_push_into_a_folder_that_sent_before_its_key_is_refused_and_makes_nothing(tmp_path, status):
    policy = DataPolicy("t-a", "s-1")
    sent_before_the_key(tmp_path, policy, status)
    log = (tmp_path / AUDIT_FILE).read_text()
    with pytest.raises(ConfigError, match=r"1 batch\(es\) of site s-1 went to the store from here without it; .*"
                                          rf"`cellguard fleet withdraw --policy POLICY --site-dir {tmp_path}` once"):
        push(sigs("t-a", "s-1"), policy, tmp_path, None, today=TODAY)
    assert not (tmp_path / KEY_FILE).exists() and not (tmp_path / "outbox").exists()
    assert (tmp_path / AUDIT_FILE).read_text() == log


def test_a_queued_batch_in_the_folder_is_no_reason_to_refuse(tmp_path):
    batch = export_batch(sigs("t-a", "s-1"), DataPolicy("t-a", "s-1"), TODAY, key=OLD_IDS)
    append_audit(tmp_path, batch, "queued", "db")  # never left: held at the push (its ids are not keyed)
    result = push(sigs("t-a", "s-1"), DataPolicy("t-a", "s-1"), tmp_path, None, today=TODAY)
    assert result.new_key == str(tmp_path / KEY_FILE)


def test_another_sites_batches_are_no_reason_to_withdraw_this_one(tmp_path):
    """The key history is the site's: another site's rows make no findings of s-1 repeat (the folder is refused for
    naming another site, ``check_same_site``, not for its key)."""
    sent_before_the_key(tmp_path, DataPolicy("t-a", "s-other"))
    check_key_history(tmp_path, DataPolicy("t-a", "s-1"))
    with pytest.raises(ConfigError, match="batches of site s-other .* the policy names site s-1"):
        push(sigs("t-a", "s-1"), DataPolicy("t-a", "s-1"), tmp_path, None, today=TODAY)


def test_cli_push_is_refused_before_the_diagnosis_in_one_line(tmp_path):
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: t-a\nsite: s-1\nexport: signatures\n")
    sent_before_the_key(tmp_path / "site", DataPolicy("t-a", "s-1"))
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path / "no-runs"), "--policy", str(policy),
                                      "--site-dir", str(tmp_path / "site")])
    assert "cellguard fleet withdraw --policy POLICY --site-dir" in one_error(result)


def test_withdraw_then_push_stores_each_finding_once(tmp_path):
    from fleet_server import admin_dsn_or_skip, store_name

    store = FleetStore(admin_dsn_or_skip(), store_name("keyhist"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    policy, site = DataPolicy("ta", "s-up"), tmp_path / "site"
    assert push(sigs("ta", "s-up"), policy, site, TenantStore(dsn), today=TODAY).new_rows == 2
    (site / KEY_FILE).unlink()  # as before the key (or a key lost): the audit log says the store has the rows
    with pytest.raises(ConfigError, match="fleet withdraw"):
        push(sigs("ta", "s-up"), policy, site, TenantStore(dsn), today=TODAY)
    assert _rows(store, "s-up") == 2
    (tmp_path / "p.yaml").write_text("tenant: ta\nsite: s-up\nexport: signatures\n")
    withdrawn = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(tmp_path / "p.yaml"), "--store", dsn,
                                         "--site-dir", str(site)])
    assert withdrawn.exit_code == 0, withdrawn.output
    assert withdrawn.stderr.startswith(f"note: {site / KEY_FILE}: a new site key") and (site / KEY_FILE).exists()
    assert push(sigs("ta", "s-up"), policy, site, TenantStore(dsn), today=TODAY).new_rows == 2
    assert _rows(store, "s-up") == 2  # each finding once, keyed


def test_withdraw_with_a_key_it_did_not_make_ends_with_its_summary(tmp_path):
    from fleet_server import admin_dsn_or_skip, store_name

    store = FleetStore(admin_dsn_or_skip(), store_name("keyperm"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    site = tmp_path / "site"
    assert push(sigs("ta", "s-perm"), DataPolicy("ta", "s-perm"), site, TenantStore(dsn), today=TODAY).new_rows == 2
    (site / KEY_FILE).chmod(0o644)  # the push's to refuse, not the withdrawal's: its rows are gone already
    (tmp_path / "p.yaml").write_text("tenant: ta\nsite: s-perm\nexport: signatures\n")
    withdrawn = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(tmp_path / "p.yaml"), "--store", dsn,
                                         "--site-dir", str(site)])
    assert withdrawn.exit_code == 0, withdrawn.output
    assert "fleet withdraw: site s-perm of ta: 2 row(s) deleted from the store" in withdrawn.stdout
    assert _rows(store, "s-perm") == 0


def _rows(store: FleetStore, site: str) -> int:
    with store.admin() as con:
        return con.execute("SELECT count(*) FROM fleet.signatures WHERE site_id = %s", (site,)).fetchone()[0]
