"""What may leave a site and what a tenant may learn: only whole records are pooled, a probe leaves only under
a policy that exports signatures (and is logged), a tenant's own rows never make up the k it is shown, an
aggregates push replaces the site's counts of its months, a bad k is one line."""

from __future__ import annotations

import datetime as dt
import json
import shutil

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature
from cellguard.record import folder_lock
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.fleet.duckdb_engine import DuckDBEngine  # noqa: E402
from cellguard.fleet.landing import write_signatures  # noqa: E402
from cellguard.fleet.store import FleetStore, RefusedAggregate, TenantStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

KEY = b"site-secret-of-the-tests"
TODAY = dt.datetime.now(dt.timezone.utc).date()


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    dsn = admin_dsn_or_skip()
    root = tmp_path_factory.mktemp("fleetrules")
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 11, "acceptance_cycles": 5, "production_cycles": 4,
                                 "faults": [{"kind": "fixture_shift", "at_cycle": 6, "dx_mm": 5.0, "dy_mm": 1.0}]}),
                 root / "run")
    store = FleetStore(dsn, store_name("rules"))
    store.install(reset=True)
    tenants = {t: store.add_tenant(t) for t in ("ta", "tb", "tc")}
    for tenant, export in (("ta", "signatures"), ("tb", "aggregates_only"), ("tc", "nothing")):
        (root / f"{tenant}.yaml").write_text(f"tenant: {tenant}\nsite: s1\nexport: {export}\n")
    return root, store, tenants


def cli(*args, dsn=None):
    return CliRunner().invoke(app, ["fleet", *map(str, args)], env={"CELLGUARD_FLEET_DSN": dsn} if dsn else None)


def cut_copy(run, folder, fraction: float = 0.9):
    """``folder`` holding the first ``fraction`` of ``run``'s record (a run cut short, or one still writing): its
    diagnosis finds the fault, with another confidence than the whole record's (another signature id)."""
    folder.mkdir(parents=True)
    data = (run / "record.mcap").read_bytes()
    (folder / "record.mcap").write_bytes(data[:int(len(data) * fraction)])
    return folder


def signatures_of(store: FleetStore, tenant: str, site: str) -> int:
    with store.admin() as con:
        return con.execute("SELECT count(*) FROM fleet.signatures WHERE tenant_id = %s AND site_id = %s",
                           (tenant, site)).fetchone()[0]


def warning_lines(result) -> list[str]:
    return [line for line in result.stderr.splitlines() if line.startswith("warning: ")]


# -- 1: only whole records are pooled --------------------------------------------------------------------------------


def test_a_truncated_record_is_not_pooled_and_its_finished_record_is_pooled_once(env, tmp_path):
    root, store, tenants = env
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s-cut\nexport: signatures\n")
    runs = tmp_path / "runs"
    cut = cut_copy(root / "run", runs / "run-7")
    args = ("push", runs, "--policy", policy, "--site-dir", tmp_path / "site", "--json")
    first = cli(*args, dsn=tenants["ta"])
    assert first.exit_code == 1, first.output
    [line] = warning_lines(first)
    assert str(cut) in line and "truncated" in line
    assert json.loads(first.stdout)["rows"] == 0 and signatures_of(store, "ta", "s-cut") == 0
    shutil.copy(root / "run" / "record.mcap", cut / "record.mcap")  # the run's whole record
    second = cli(*args, dsn=tenants["ta"])
    assert second.exit_code == 0, second.output
    rows = json.loads(second.stdout)["rows"]
    assert rows >= 1 and signatures_of(store, "ta", "s-cut") == rows  # each finding once, as the whole record has it


def test_a_record_still_being_written_is_not_pooled(env, tmp_path):
    root, store, tenants = env
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s-live\nexport: signatures\n")
    live = cut_copy(root / "run", tmp_path / "runs" / "live")
    whole = tmp_path / "runs" / "whole"
    whole.mkdir()
    shutil.copy(root / "run" / "record.mcap", whole / "record.mcap")
    fd = folder_lock.hold(live)  # its run holds the folder, as a run does while it writes
    try:
        out = cli("push", tmp_path / "runs", "--policy", policy, "--site-dir", tmp_path / "site", "--json",
                  dsn=tenants["ta"])
    finally:
        folder_lock.release(fd)
    assert out.exit_code == 1, out.output
    [line] = warning_lines(out)
    assert str(live) in line and "still being written" in line and "once its run has ended" in line
    assert signatures_of(store, "ta", "s-live") == json.loads(out.stdout)["rows"] >= 1  # the whole run's only
    alone = cli("push", whole, "--policy", policy, "--site-dir", tmp_path / "site", "--json", dsn=tenants["ta"])
    assert json.loads(alone.stdout)["new_rows"] == 0  # the same findings: nothing of the live run went


def test_a_record_that_cannot_even_be_opened_is_left_out_and_the_others_go(env, tmp_path):
    """Cut inside its first chunk (or a run's first seconds, before its first chunk): the whole push stopped, exit 2,
    nothing sent."""
    root, store, tenants = env
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s-start\nexport: signatures\n")
    cut = cut_copy(root / "run", tmp_path / "runs" / "start", fraction=0.001)
    whole = tmp_path / "runs" / "whole"
    whole.mkdir()
    shutil.copy(root / "run" / "record.mcap", whole / "record.mcap")
    out = cli("push", tmp_path / "runs", "--policy", policy, "--site-dir", tmp_path / "site", "--json",
              dsn=tenants["ta"])
    assert out.exit_code == 1, out.output
    [line] = warning_lines(out)
    assert str(cut) in line and "its findings were left out" in line
    assert signatures_of(store, "ta", "s-start") == json.loads(out.stdout)["rows"] >= 1  # the whole run's


# -- 2: a probe leaves only under export: signatures, and is logged --------------------------------------------------


@pytest.mark.parametrize("tenant", ["tb", "tc"], ids=["aggregates_only", "nothing"])
def test_similar_under_a_policy_that_exports_no_signatures_sends_nothing(env, tmp_path, tenant):
    root, _, tenants = env
    out = cli("similar", root / "run", "--policy", root / f"{tenant}.yaml", "--site-dir", tmp_path / "site",
              dsn=tenants[tenant])
    assert out.exit_code == 2, out.output
    assert out.stderr.count("\n") == 1 and out.stderr.startswith("error: --policy: export:")
    assert "nothing sent" in out.stderr and out.stdout == ""
    assert not (tmp_path / "site").exists()  # nothing to log: nothing left


def test_the_probes_similar_sends_are_in_the_audit_log(env, tmp_path):
    root, _, tenants = env
    out = cli("similar", root / "run", "--policy", root / "ta.yaml", "--site-dir", tmp_path / "site", "--json",
              dsn=tenants["ta"])
    assert out.exit_code == 0, out.output
    findings = json.loads(out.stdout)["findings"]
    entries = json.loads(cli("audit", "--site-dir", tmp_path / "site", "--json").stdout)["entries"]
    assert [(e["status"], e["rows"], e["tenant_id"], e["site_id"]) for e in entries] == \
        [("probed", len(findings), "ta", "s1")]


# -- 3: a tenant's own rows never make up its k; sites are each tenant's ---------------------------------------------


def found(tenant: str, n: int, cause: str = "secret_cause", model: str = "arm-x") -> list[Signature]:
    return [Signature(tenant, "s-1", TODAY.isoformat(), cause, 0.9, model, "pick", {"f1": 1.0 + i}, i,
                      policy_version="pv1", recovery="retry_grasp", recovery_outcome="success") for i in range(n)]


@pytest.fixture(scope="module")
def crafted(tmp_path_factory):
    """Four victims hold ``secret_cause``; six customers (the victims too) hold ``other``; t-evil crafts one
    ``secret_cause`` row of its own (in the store and in its lake folder). Every tenant's site is ``s-1``."""
    store = FleetStore(admin_dsn_or_skip(), store_name("rules_k"))
    store.install(reset=True)
    lake = tmp_path_factory.mktemp("lake")
    held = {"t-a": 3, "t-b": 3, "t-c": 3, "t-d": 3, "t-e": 0, "t-f": 0}
    dsns = {}
    for tenant, n in (*held.items(), ("t-evil", 1)):
        dsns[tenant] = store.add_tenant(tenant)
        rows = found(tenant, n) + (found(tenant, 1, "other", "arm-y") if tenant != "t-evil" else [])
        batch = export_batch(rows, DataPolicy(tenant, "s-1"), key=KEY)
        TenantStore(dsns[tenant]).push(batch)
        write_signatures(lake, batch.signatures, f"b-{tenant}")
    return store, dsns, lake


@pytest.mark.parametrize("name", ["frequency", "introduced", "fixes"])
def test_a_tenants_own_crafted_row_does_not_make_up_the_k_it_is_shown(crafted, name):
    _, dsns, lake = crafted
    on_store = TenantStore(dsns["t-evil"]).run(name)
    on_lake = DuckDBEngine(lake, "t-evil").run(name)
    assert on_store == on_lake and {r["cause"] for r in on_store} == {"other"}  # 6 other customers
    # secret_cause: 4 customers besides t-evil, under k = 5; to a customer who holds none of it, 5
    assert "secret_cause" in {r["cause"] for r in TenantStore(dsns["t-e"]).run(name)}


def test_a_tenant_is_refused_while_fewer_than_k_other_customers_have_signatures(crafted):
    store, dsns, lake = crafted
    store.set_min_customers(7)  # 7 customers, 6 besides each caller
    try:
        with pytest.raises(RefusedAggregate, match="fewer than 7 customers"):
            TenantStore(dsns["t-evil"]).run("frequency")
    finally:
        store.set_min_customers(5)
    with pytest.raises(RefusedAggregate, match="fewer than 7 customers"):
        DuckDBEngine(lake, "t-evil", min_customers=7).run("frequency")


def test_sites_are_counted_per_tenant(crafted):
    _, _, lake = crafted
    [row] = [r for r in DuckDBEngine(lake).run("frequency", {"k": 1}) if r["cause"] == "secret_cause"]
    assert (row["customers"], row["sites"]) == (5, 5)  # five customers, each with its own "s-1"


# -- 4: an aggregates push replaces the site's counts of its months --------------------------------------------------


def test_aggregates_pushed_again_under_a_policy_that_withholds_more_are_counted_once(env):
    _, store, tenants = env
    found = [Signature("ta", "s-agg", TODAY.isoformat(), "friction", 0.8, model, "arm-pick-place", {"f": 1.0 + i})
             for i, model in enumerate(["arm5", "arm5", "arm6", "arm6"])]
    plain = DataPolicy("ta", "s-agg", export="aggregates_only", min_group_size=2)
    merged = DataPolicy("ta", "s-agg", export="aggregates_only", min_group_size=2, withheld=("robot_model",))
    for policy in (plain, merged):
        TenantStore(tenants["ta"]).push(export_batch(found, policy, key=KEY))
    with store.admin() as con:
        rows = con.execute("SELECT robot_model, signatures FROM fleet.aggregates WHERE site_id = 's-agg'").fetchall()
    assert rows == [(None, 4)]  # the per-model rows of the same month are gone: 4 signatures, not 8


# -- 6: k checked as on the lake; a store error is one line ----------------------------------------------------------


@pytest.mark.parametrize("k", ["3000000000", "0", "-5"])
def test_a_k_out_of_range_is_one_line_exit_2_on_the_store_and_the_lake(env, tmp_path, k):
    root, _, tenants = env
    lake = tmp_path / "lake"
    write_signatures(lake, export_batch(found("ta", 1), DataPolicy("ta", "s-1"), key=KEY).signatures, "b")
    for out in (cli("query", "frequency", "--k", k, dsn=tenants["ta"]),
                cli("query", "frequency", "--k", k, "--lake", lake, "--tenant", "ta")):
        assert out.exit_code == 2, out.output
        assert out.stderr == f"error: query frequency: parameter k must be 1..1000000, got {k}\n"


def test_a_store_error_in_a_query_is_one_line_exit_2(env):
    _, store, tenants = env
    with store.admin() as con:  # a store installed without the function
        con.execute("DROP FUNCTION fleet.q_fixes(int)")
        con.commit()
    try:
        out = cli("query", "fixes", dsn=tenants["ta"])
    finally:
        store.install()  # brought up to date: the function is back
    assert out.exit_code == 2, out.output
    assert out.stderr.count("\n") == 1 and "query fixes failed" in out.stderr and "q_fixes" in out.stderr
    assert "Traceback" not in out.output
