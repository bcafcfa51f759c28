"""The site folder's files (audit log, site key, outbox) are written only in it: a --site-dir that is a file, or
one whose files are links, is one line and exit 2 before anything is made, sent or deleted (a file ended the push
in a traceback after the diagnosis; a link to nothing took the audit log outside the site). `fleet withdraw` logs
each deletion in the site's audit log, and a policy must say what it exports (its absence exported signatures)."""

from __future__ import annotations

import datetime as dt
import json

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.audit import append_audit, read_audit
from cellguard.fleet.export import export_batch
from cellguard.fleet.landing import write_signatures
from cellguard.fleet.policy import PolicyError, load_policy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import site_key

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY_TEXT = "tenant: ta\nsite: s1\nexport: signatures\n"


def sigs(n: int = 2) -> list[Signature]:
    return [Signature("ta", "s1", TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                      {"current_rms.elbow": 6.0 + i}, 7, 1) for i, cause in enumerate(["friction", "servo"][:n])]


def policy_file(tmp_path, text: str = POLICY_TEXT):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    return path


def one_error(result) -> str:
    assert result.exit_code == 2 and result.stdout == "", result.output
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("error: "), result.stderr
    return result.stderr


def cli_push(tmp_path, site, *more: str):
    return CliRunner().invoke(app, ["fleet", "push", str(tmp_path / "no-runs"), "--policy", str(policy_file(tmp_path)),
                                    "--site-dir", str(site), *more])


# -- a --site-dir that is a file ------------------------------------------------------------------------------------


def test_push_into_a_site_dir_that_is_a_file_is_one_line_and_leaves_it(tmp_path):
    site = tmp_path / "sd"
    site.write_text("not a folder\n")
    assert f"--site-dir {site}: not a folder" in one_error(cli_push(tmp_path, site))
    with pytest.raises(ConfigError, match="not a folder"):
        push(sigs(), load_policy(policy_file(tmp_path)), site, None, today=TODAY)
    assert site.read_text() == "not a folder\n"


def test_a_site_key_that_cannot_be_made_is_one_error_naming_it(tmp_path):
    """The temporary key's removal, from a folder that could not be made, raised NotADirectoryError past it."""
    (tmp_path / "sd").write_text("")
    with pytest.raises(OutputError, match=r"site key .*sd/site.key: cannot write"):
        site_key(tmp_path / "sd")


# -- links in the site folder ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["audit.jsonl", "site.key", "outbox"])
def test_push_through_a_link_in_the_site_folder_is_refused_and_writes_nothing_outside(tmp_path, name):
    site, outside = tmp_path / "site", tmp_path / "elsewhere" / "target"
    site.mkdir()
    (site / name).symlink_to(outside)
    assert f"--site-dir {site}: {name} is a link to {outside}; the site's files are written only in its folder" in \
        one_error(cli_push(tmp_path, site))
    with pytest.raises(ConfigError, match=f"{name} is a link"):
        push(sigs(), load_policy(policy_file(tmp_path)), site, None, today=TODAY)
    assert not outside.parent.exists() and sorted(p.name for p in site.iterdir()) == [name]


def test_the_audit_log_is_never_appended_through_a_link(tmp_path):
    """What the push's check does not see (a link put there after it): the append itself refuses it."""
    outside = tmp_path / "elsewhere.jsonl"
    outside.write_text("someone else's file\n")
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "audit.jsonl").symlink_to(outside)
    batch = export_batch(sigs(), load_policy(policy_file(tmp_path)), TODAY, key=b"k")
    with pytest.raises(OutputError, match="audit.jsonl: a link; the site's files are written only in its folder"):
        append_audit(tmp_path / "site", batch, "queued", "nowhere")
    assert outside.read_text() == "someone else's file\n"


def test_a_batch_is_never_queued_through_a_link_in_the_outbox(tmp_path):
    site, outside = tmp_path / "site", tmp_path / "elsewhere.json"
    policy = load_policy(policy_file(tmp_path))
    batch = export_batch(sigs(), policy, TODAY, key=site_key(site))
    (site / "outbox").mkdir()
    (site / "outbox" / f"{batch.batch_id}.json").symlink_to(outside)
    with pytest.raises(ConfigError, match=f"outbox/{batch.batch_id}.json is a link to {outside}"):
        push(sigs(), policy, site, None, today=TODAY)
    assert not outside.exists()


# -- fleet withdraw -------------------------------------------------------------------------------------------------


def pooled_lake(tmp_path):
    lake = tmp_path / "lake"
    write_signatures(lake, export_batch(sigs(), load_policy(policy_file(tmp_path)), TODAY, key=b"k").signatures, "b1")
    return lake


def withdraw(tmp_path, lake, site, *more: str):
    return CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(policy_file(tmp_path)), "--lake", str(lake),
                                    "--site-dir", str(site), *more])


def in_lake(lake) -> int:
    return len(list(lake.rglob("*.parquet")))


def test_withdraw_logs_each_deletion_in_the_site_audit_log(tmp_path):
    lake, site = pooled_lake(tmp_path), tmp_path / "site"
    site.mkdir()
    result = withdraw(tmp_path, lake, site, "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["lake_signatures"] == 2 and in_lake(lake) == 0
    (entry,) = read_audit(site)
    assert {k: entry[k] for k in ("status", "rows", "destination", "tenant_id", "site_id", "batch_id")} == \
        {"status": "withdrawn", "rows": 2, "destination": str(lake), "tenant_id": "ta", "site_id": "s1", "batch_id": ""}
    again = withdraw(tmp_path, lake, site)  # nothing left: logged too, a withdrawal asked for
    assert again.exit_code == 0 and [e["rows"] for e in read_audit(site)] == [2, 0]


def test_a_policy_written_before_export_was_required_still_withdraws(tmp_path):
    """Pooled under a file with no export (it exported signatures), taken back with that same file."""
    lake, site = pooled_lake(tmp_path), tmp_path / "site"
    site.mkdir()
    old = tmp_path / "old.yaml"
    old.write_text("tenant: ta\nsite: s1\n")
    result = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(old), "--lake", str(lake),
                                      "--site-dir", str(site)])
    assert result.exit_code == 0, result.output
    assert in_lake(lake) == 0 and [e["status"] for e in read_audit(site)] == ["withdrawn"]


@pytest.mark.parametrize("what", ["file", "missing", "linked-log"])
def test_withdraw_into_a_site_dir_it_cannot_log_in_deletes_nothing(tmp_path, what):
    lake, site = pooled_lake(tmp_path), tmp_path / "site"
    if what == "file":
        site.write_text("")
    elif what == "linked-log":
        site.mkdir()
        (site / "audit.jsonl").symlink_to(tmp_path / "elsewhere.jsonl")
    error = one_error(withdraw(tmp_path, lake, site))
    assert {"file": "not a folder", "missing": "no such folder", "linked-log": "audit.jsonl is a link"}[what] in error
    assert in_lake(lake) == 2 and not (tmp_path / "elsewhere.jsonl").exists()


def test_withdraw_from_the_store_is_logged_and_a_site_dir_file_deletes_nothing_there(tmp_path):
    from fleet_server import admin_dsn_or_skip, store_name

    from cellguard.fleet.store import FleetStore, TenantStore

    store = FleetStore(admin_dsn_or_skip(), store_name("sitedir"))
    store.install(reset=True)
    dsn = store.add_tenant("ta")
    site = tmp_path / "site"
    assert push(sigs(), load_policy(policy_file(tmp_path)), site, TenantStore(dsn), today=TODAY).new_rows == 2
    (tmp_path / "sd").write_text("")
    args = ["fleet", "withdraw", "--policy", str(policy_file(tmp_path)), "--store", dsn, "--site-dir"]
    assert "not a folder" in one_error(CliRunner().invoke(app, args + [str(tmp_path / "sd")]))
    assert TenantStore(dsn).run("frequency", {}, scope="own")  # still there
    result = CliRunner().invoke(app, args + [str(site)])
    assert result.exit_code == 0, result.output
    last = read_audit(site)[-1]
    assert (last["status"], last["rows"], last["destination"]) == ("withdrawn", 2, TenantStore(dsn).where)
    assert not TenantStore(dsn).run("frequency", {}, scope="own")


# -- a policy says what it exports ----------------------------------------------------------------------------------


def test_a_policy_without_export_is_refused_naming_the_file_and_the_choices(tmp_path):
    path = policy_file(tmp_path, "tenant: ta\nsite: s1\n")
    with pytest.raises(PolicyError, match=rf"^{path}: export: required, .*signatures \| aggregates_only \| nothing$"):
        load_policy(path)
    site = tmp_path / "site"
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(path), "--site-dir", str(site)])
    assert f"{path}: export: required" in one_error(result) and not site.exists()
