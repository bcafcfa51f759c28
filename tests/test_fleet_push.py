"""A push against a real PostgreSQL server (``.ci/fleet.sh`` starts one) when the outbox holds
what the policy in force no longer allows, what the store refuses or what cannot be read, and a
lake fed by a growing folder: the policy in force decides what leaves, one bad batch never
blocks the others, nothing queued is lost, the lake holds each signature once."""

from __future__ import annotations

import datetime as dt
import json

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.cli import app  # noqa: E402
from cellguard.errors import OutputError  # noqa: E402
from cellguard.fleet.audit import read_audit  # noqa: E402
from cellguard.fleet.duckdb_engine import DuckDBEngine  # noqa: E402
from cellguard.fleet.export import export_batch  # noqa: E402
from cellguard.fleet.outbox import Outbox  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.signature import SCHEMA_VERSION, Signature  # noqa: E402
from cellguard.fleet.store import FleetStore, TenantStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

TODAY = dt.datetime.now(dt.timezone.utc).date()
DOWN = "host=127.0.0.1 port=1 dbname=x user=x password=x"  # nothing listens on port 1
KEY = b"site-secret-of-the-tests"  # the site key signature ids are keyed with (site_key.py)


def sig(tenant: str, site: str, cause: str, n: int = 0) -> Signature:
    return Signature(tenant, site, TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0 + n, "tracking_rms.elbow": 1.2}, 7, 1, "pv-1", "cal-1", "0.1.0")


def sigs(tenant: str, site: str, n: int = 2) -> list[Signature]:
    causes = ["friction", "fixture_shift", "servo", "tool_slip"][:n]
    return [sig(tenant, site, cause, i) for i, cause in enumerate(causes)]


@pytest.fixture(scope="module")
def fleet():
    dsn = admin_dsn_or_skip()
    store = FleetStore(dsn, store_name("push"))
    store.install(reset=True)
    return store, {t: store.add_tenant(t) for t in ("ta", "tb")}


def rows_of_site(store: FleetStore, site: str) -> int:
    with store.admin() as con:
        return con.execute("SELECT count(*) FROM fleet.signatures WHERE site_id = %s", (site,)).fetchone()[0] + \
            con.execute("SELECT count(*) FROM fleet.aggregates WHERE site_id = %s", (site,)).fetchone()[0]


def queue_while_down(site_dir, policy: DataPolicy, signatures: list[Signature]) -> None:
    first = push(signatures, policy, site_dir, TenantStore(DOWN))
    assert first.unavailable and first.queued == 1


# -- F3: the policy in force decides what leaves -------------------------------------------------------------------


@pytest.mark.parametrize("now", [
    dict(export="nothing"),
    dict(export="aggregates_only", min_group_size=2),
    dict(withheld=("effects",)),
    dict(withheld=("policy_version", "robot_model")),
    dict(retention_days=1),
], ids=["nothing", "aggregates_only", "withheld-effects", "withheld-versions", "retention"])
def test_a_batch_queued_before_a_stricter_policy_is_held_at_the_site(fleet, tmp_path, now, request):
    store, dsns = fleet
    site = "s3-" + request.node.callspec.id
    before = DataPolicy("ta", site)
    old = [Signature(**{**s.__dict__, "created_date": (TODAY - dt.timedelta(days=3)).isoformat()})
           for s in sigs("ta", site)]  # three days old: still inside the earlier policy's retention of 365 days
    queue_while_down(tmp_path, before, old)
    stricter = DataPolicy("ta", site, **now)
    result = push([], stricter, tmp_path, TenantStore(dsns["ta"]))
    assert rows_of_site(store, site) == 0  # nothing the policy in force forbids has left the site
    assert (result.sent_batches, result.queued, len(result.held)) == (0, 1, 1)
    assert stricter.version in result.held[0] and "\n" not in result.held[0]
    held = read_audit(tmp_path)[-1]
    assert (held["status"], held["policy_in_force"], held["policy_version"]) == ("held", stricter.version,
                                                                                 before.version)
    assert held["reason"]
    # pushed again under the same policy: held again, logged once (every push added a line)
    assert len(push([], stricter, tmp_path, TenantStore(dsns["ta"])).held) == 1
    assert [e["status"] for e in read_audit(tmp_path)].count("held") == 1
    # held, not lost: under a policy that allows it again, it goes
    again = push([], before, tmp_path, TenantStore(dsns["ta"]))
    assert (again.sent_batches, again.new_rows, again.queued) == (1, 2, 0)
    assert read_audit(tmp_path)[-1]["status"] == "sent"


def test_a_queued_batch_the_policy_in_force_allows_still_goes(fleet, tmp_path):
    store, dsns = fleet
    queue_while_down(tmp_path, DataPolicy("ta", "s3-ok", withheld=("effects", "robot_model")), sigs("ta", "s3-ok"))
    looser = DataPolicy("ta", "s3-ok", withheld=("effects",))  # withholds less: the batch shows nothing it keeps
    result = push([], looser, tmp_path, TenantStore(dsns["ta"]))
    assert (result.sent_batches, result.new_rows, result.held) == (1, 2, ())
    sent = read_audit(tmp_path)[-1]
    assert (sent["status"], sent["policy_in_force"]) == ("sent", looser.version)


def test_cli_push_under_export_nothing_holds_what_was_queued_before(fleet, tmp_path):
    store, dsns = fleet
    queue_while_down(tmp_path / "site", DataPolicy("ta", "s3-cli"), sigs("ta", "s3-cli"))
    policy = tmp_path / "nothing.yaml"
    policy.write_text("tenant: ta\nsite: s3-cli\nexport: nothing\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(policy),
                                      "--site-dir", str(tmp_path / "site"), "--store", dsns["ta"], "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert (out["sent_batches"], out["new_rows"], out["queued"], len(out["held"])) == (0, 0, 1, 1)
    assert rows_of_site(store, "s3-cli") == 0
    (note,) = [ln for ln in result.stderr.splitlines() if "held" in ln]
    assert "the policy exports nothing" in note and "outbox" in note


# -- F4: one refused or unreadable batch never blocks the others ---------------------------------------------------


def test_a_batch_of_another_tenant_is_held_and_the_others_go(fleet, tmp_path):
    store, dsns = fleet
    queue_while_down(tmp_path, DataPolicy("tb", "s4-b"), sigs("tb", "s4-b"))  # another tenant's, in this outbox
    result = push(sigs("ta", "s4-a"), DataPolicy("ta", "s4-a"), tmp_path, TenantStore(dsns["ta"]))
    assert (result.sent_batches, result.new_rows, result.queued, len(result.held)) == (1, 2, 1, 1)
    assert "tb/s4-b" in result.held[0]
    assert rows_of_site(store, "s4-a") == 2 and rows_of_site(store, "s4-b") == 0


def test_batches_the_store_refuses_stay_queued_and_do_not_stop_the_push(fleet, tmp_path):
    store, dsns = fleet
    policy = DataPolicy("tb", "s4-r")  # the policy names tb, the credentials are ta's: row-level security refuses
    queue_while_down(tmp_path, policy, sigs("tb", "s4-r", 2))
    result = push(sigs("tb", "s4-r", 3), policy, tmp_path, TenantStore(dsns["ta"]))
    assert (result.sent_batches, result.queued, len(result.failed)) == (0, 2, 2)  # both tried, both kept
    assert all("refused the batch of tenant tb" in f and "it stays queued" in f for f in result.failed)
    assert [e["status"] for e in read_audit(tmp_path)][-2:] == ["refused", "refused"]
    assert rows_of_site(store, "s4-r") == 0


def test_a_batch_of_a_newer_schema_stays_queued_and_the_others_go(fleet, tmp_path):
    store, dsns = fleet
    policy = DataPolicy("ta", "s4-n")
    newer = export_batch(sigs("ta", "s4-n"), policy, key=KEY).to_dict()
    newer["signatures"][0] = {**newer["signatures"][0], "schema_version": SCHEMA_VERSION + 1}
    box = tmp_path / "outbox"
    box.mkdir()
    (box / "newer.json").write_text(json.dumps(newer))
    result = push(sigs("ta", "s4-n", 3), policy, tmp_path, TenantStore(dsns["ta"]))
    assert (result.sent_batches, result.new_rows, result.queued) == (1, 3, 1)
    (line,) = result.failed
    assert "newer.json: signature.schema_version" in line and "it stays queued" in line
    assert json.loads((box / "newer.json").read_text()) == newer


# -- F5: a growing folder pushed again adds only its new signatures to the lake ------------------------------------


def test_pushing_a_growing_folder_again_lands_each_signature_once(fleet, tmp_path):
    _, dsns = fleet
    policy, lake = DataPolicy("ta", "s5"), tmp_path / "lake"
    push(sigs("ta", "s5", 2), policy, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    second = push(sigs("ta", "s5", 3), policy, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert (second.new_rows, second.duplicate_rows) == (1, 2)
    on_disk = pq.ParquetDataset(str(lake / "tenant=ta" / "signatures")).read()
    assert sorted(on_disk.column("cause").to_pylist()) == ["fixture_shift", "friction", "servo"]
    effects = pq.ParquetDataset(str(lake / "tenant=ta" / "effects")).read()
    assert effects.num_rows == 3 * 2
    rows = DuckDBEngine(lake).run("frequency", {"k": 1})
    assert sum(r["signatures"] for r in rows) == 3
    push(sigs("ta", "s5", 3), policy, tmp_path / "site", TenantStore(dsns["ta"]), lake)  # the same folder again
    assert pq.ParquetDataset(str(lake / "tenant=ta" / "signatures")).read().num_rows == 3


def test_a_lake_that_is_a_file_is_refused_before_anything_is_sent(fleet, tmp_path):
    store, dsns = fleet
    lake = tmp_path / "lake"
    lake.write_text("not a folder")
    with pytest.raises(OutputError, match="--lake .*lake: not a folder"):
        push(sigs("ta", "s6"), DataPolicy("ta", "s6"), tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert rows_of_site(store, "s6") == 0 and not (tmp_path / "site").exists()
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s6\nexport: nothing\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(policy), "--lake",
                                      str(lake / "x"), "--site-dir", str(tmp_path / "site"), "--store", dsns["ta"]])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "is not a folder" in result.stderr
    assert not (tmp_path / "site").exists()
    assert Outbox(tmp_path / "site").pending() == []


# -- a queued batch that is malformed stays queued; the store and the lake never diverge ---------------------------


MALFORMED = [  # (case, field, a value that is not what a signature holds there)
    ("effect-quoted", "effects", {"current_rms.elbow": "1e3"}),
    ("effect-nan", "effects", {"current_rms.elbow": float("nan")}),
    ("confidence-quoted", "confidence", "0.5"),
    ("onset-quoted", "onset_cycle", "7"),
    ("delay-negative", "detection_delay_cycles", -100),
    ("cause-escape-code", "cause", "friction\x1b[2J"),
    ("another-site", "site_id", "s9-not-mine"),
]


@pytest.mark.parametrize("case,field,value", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_a_malformed_queued_batch_stays_queued_and_the_others_go(fleet, tmp_path, case, field, value):
    store, dsns = fleet
    site, lake = "s8-" + case, tmp_path / "lake"
    policy = DataPolicy("ta", site)
    raw = export_batch(sigs("ta", site, 1), policy, key=KEY).to_dict(with_id=False)
    raw["signatures"][0][field] = value
    (tmp_path / "site" / "outbox").mkdir(parents=True)
    bad = tmp_path / "site" / "outbox" / "crafted.json"
    bad.write_text(json.dumps(raw))
    result = push(sigs("ta", site, 3), policy, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert (result.sent_batches, result.new_rows, result.queued) == (1, 3, 1)
    (line,) = result.failed
    assert "crafted.json: batch.signatures[0]" in line or f"crafted.json: signature.{field}" in line
    assert "\n" not in line and "\x1b" not in line and bad.exists()
    assert rows_of_site(store, site) == 3 == sum(r["signatures"] for r in DuckDBEngine(lake).run("frequency", {"k": 1}))


def test_a_lake_that_cannot_take_a_batch_leaves_the_store_as_it_was(fleet, tmp_path):
    store, dsns = fleet
    policy, lake = DataPolicy("ta", "s8-lake"), tmp_path / "lake"
    blocked = lake / "tenant=ta" / "signatures" / f"date={TODAY.isoformat()}"
    blocked.parent.mkdir(parents=True)
    blocked.write_text("a file where the lake needs a folder")
    first = push(sigs("ta", "s8-lake"), policy, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert (first.sent_batches, first.queued, rows_of_site(store, "s8-lake")) == (0, 1, 0)
    (line,) = first.failed
    assert f"{blocked}: cannot create the folder" in line and "it stays queued" in line
    blocked.unlink()
    again = push([], policy, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert (again.sent_batches, again.queued, rows_of_site(store, "s8-lake")) == (1, 0, 2)
    assert sum(r["signatures"] for r in DuckDBEngine(lake).run("frequency", {"k": 1})) == 2


# -- what the store and the lake hold follows the policy in force ----------------------------------------------------


def test_a_push_under_a_policy_that_withholds_more_replaces_what_it_sent(fleet, tmp_path):
    store, dsns = fleet
    lake = tmp_path / "lake"
    push(sigs("ta", "s9-w"), DataPolicy("ta", "s9-w"), tmp_path / "site", TenantStore(dsns["ta"]), lake)
    stricter = DataPolicy("ta", "s9-w", withheld=("confidence", "policy_version", "effects"))
    result = push(sigs("ta", "s9-w"), stricter, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert (result.new_rows, result.duplicate_rows) == (2, 0)  # the same two findings, now with less in them
    with store.admin() as con:
        rows = con.execute("SELECT confidence, policy_version, cause FROM fleet.signatures WHERE site_id = 's9-w'")
        assert sorted(rows.fetchall()) == [(None, None, "fixture_shift"), (None, None, "friction")]
        assert con.execute("SELECT count(*) FROM fleet.effects e JOIN fleet.signatures s USING (tenant_id, "
                           "signature_id) WHERE s.site_id = 's9-w'").fetchone()[0] == 0
    on_disk = pq.ParquetDataset(str(lake / "tenant=ta" / "signatures")).read()
    assert on_disk.num_rows == 2 and on_disk.column("confidence").null_count == 2
    assert pq.ParquetDataset(str(lake / "tenant=ta" / "effects")).read().num_rows == 0
    again = push(sigs("ta", "s9-w"), stricter, tmp_path / "site", TenantStore(dsns["ta"]), lake)
    assert (again.new_rows, again.duplicate_rows) == (0, 2)


def test_the_aggregates_of_a_growing_folder_pushed_again_are_counted_once(fleet, tmp_path):
    store, dsns = fleet
    policy = DataPolicy("ta", "s9-a", export="aggregates_only", min_group_size=2)
    found = [sig("ta", "s9-a", "friction", n) for n in range(3)]
    push(found[:2], policy, tmp_path, TenantStore(dsns["ta"]))
    second = push(found, policy, tmp_path, TenantStore(dsns["ta"]))
    third = push(found, policy, tmp_path, TenantStore(dsns["ta"]))
    assert (second.new_rows, third.new_rows, third.duplicate_rows) == (1, 0, 1)
    with store.admin() as con:
        assert con.execute("SELECT count(*), sum(signatures) FROM fleet.aggregates WHERE site_id = 's9-a'") \
            .fetchone() == (1, 3)


def test_every_push_applies_the_retention_even_with_nothing_to_send(fleet, tmp_path):
    store, dsns = fleet
    lake, site, tenant = tmp_path / "lake", tmp_path / "site", TenantStore(dsns["ta"])
    long_ago = (TODAY - dt.timedelta(days=2000)).isoformat()
    past = lambda found: [Signature(**{**s.__dict__, "created_date": long_ago}) for s in found]  # noqa: E731
    push(past(sigs("ta", "s9-r")), DataPolicy("ta", "s9-r", retention_days=36500), site, tenant, lake)
    push(past([sig("ta", "s9-r", "servo", n) for n in range(2)]),
         DataPolicy("ta", "s9-r", export="aggregates_only", min_group_size=2, retention_days=36500), site, tenant)
    assert rows_of_site(store, "s9-r") == 3  # 2 signatures and 1 count, all kept under 100 years' retention
    result = push([], DataPolicy("ta", "s9-r", export="nothing", retention_days=30), site, tenant, lake)
    assert (result.failed, result.unavailable) == ((), None)
    assert rows_of_site(store, "s9-r") == 0
    assert not list((lake / "tenant=ta" / "signatures").rglob("*.parquet"))


def test_cli_withdraw_deletes_what_the_site_pooled_from_the_store_and_the_lake(fleet, tmp_path):
    store, dsns = fleet
    lake = tmp_path / "lake"
    push(sigs("ta", "s9-x"), DataPolicy("ta", "s9-x"), tmp_path / "site", TenantStore(dsns["ta"]), lake)
    push(sigs("ta", "s9-y"), DataPolicy("ta", "s9-y"), tmp_path / "site-y", TenantStore(dsns["ta"]), lake)
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s9-x\nexport: nothing\n")
    result = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(policy), "--store", dsns["ta"],
                                      "--lake", str(lake), "--site-dir", str(tmp_path / "site"), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == {"tenant": "ta", "site": "s9-x", "store_rows": 2, "lake_signatures": 2}
    assert (rows_of_site(store, "s9-x"), rows_of_site(store, "s9-y")) == (0, 2)
    assert {r["site_id"] for r in DuckDBEngine(lake).run("similar", {"site": "none", "limit": 10},
                                                        [("current_rms.elbow", 6.0)])} == {"s9-y"}


def test_cli_withdraw_with_an_unreadable_lake_deletes_nothing_anywhere(fleet, tmp_path):
    store, dsns = fleet
    lake = tmp_path / "lake"
    push(sigs("ta", "s9-u"), DataPolicy("ta", "s9-u"), tmp_path / "site", TenantStore(dsns["ta"]), lake)
    (next((lake / "tenant=ta" / "signatures").rglob("*.parquet"))).write_bytes(b"not parquet")
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s9-u\nexport: nothing\n")
    result = CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(policy), "--store", dsns["ta"],
                                      "--lake", str(lake), "--site-dir", str(tmp_path / "site")])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "cannot read it" in result.stderr
    assert rows_of_site(store, "s9-u") == 2  # the store's rows stay until the lake's can go too


def test_cli_push_and_audit_lines_are_not_wrapped(fleet, tmp_path):
    _, dsns = fleet
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s9-wrap-a-long-site-name-for-the-line\nexport: nothing\n")
    site = tmp_path / "a-site-folder-with-a-name-long-enough-to-push-a-line-past-eighty-columns"
    pushed = CliRunner().invoke(app, ["fleet", "push", str(tmp_path / "none"), "--policy", str(policy),
                                      "--store", dsns["ta"], "--site-dir", str(site)], terminal_width=80)
    assert pushed.exit_code == 0, pushed.output
    assert pushed.stdout.count("\n") == 1 and len(pushed.stdout) > 81
    audit = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)], terminal_width=80)
    assert audit.exit_code == 0 and audit.stdout.count("\n") == 2  # the title and one entry, each on one line
    assert "batch=" in audit.stdout.splitlines()[1]


def test_a_batch_queued_without_the_site_key_is_held_not_sent(fleet, tmp_path):
    """Batches queued by the version before the site key carry unkeyed ids, from which withheld fields can be
    recovered: the push after the upgrade sent them beside the new keyed rows (two rows for one finding)."""
    _, dsns = fleet
    policy = DataPolicy("ta", "s3-old", withheld=("robot_model",))
    queue_while_down(tmp_path, policy, sigs("ta", "s3-old"))
    (path,) = (tmp_path / "outbox").glob("*.json")
    raw = json.loads(path.read_text())
    del raw["key_id"], raw["batch_id"]  # as the version before wrote it
    path.write_text(json.dumps(raw))
    result = push([], policy, tmp_path, TenantStore(dsns["ta"]))
    assert result.sent_batches == 0 and result.queued == 1
    assert len(result.held) == 1 and "not made with this site's key" in result.held[0]
    assert read_audit(tmp_path)[-1]["status"] == "held"
