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
from fleet_server import admin_dsn_or_skip  # noqa: E402

TODAY = dt.datetime.now(dt.timezone.utc).date()
DOWN = "host=127.0.0.1 port=1 dbname=x user=x password=x"  # nothing listens on port 1


def sig(tenant: str, site: str, cause: str, n: int = 0) -> Signature:
    return Signature(tenant, site, TODAY.isoformat(), cause, 0.8, "arm5", "arm-pick-place",
                     {"current_rms.elbow": 6.0 + n, "tracking_rms.elbow": 1.2}, 7, 1, "pv-1", "cal-1", "0.1.0")


def sigs(tenant: str, site: str, n: int = 2) -> list[Signature]:
    causes = ["friction", "fixture_shift", "servo", "tool_slip"][:n]
    return [sig(tenant, site, cause, i) for i, cause in enumerate(causes)]


@pytest.fixture(scope="module")
def fleet():
    dsn = admin_dsn_or_skip()
    store = FleetStore(dsn, "cgtest_push")
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
    newer = export_batch(sigs("ta", "s4-n"), policy).to_dict()
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
