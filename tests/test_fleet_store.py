"""The fleet store against a real PostgreSQL server (``.ci/fleet.sh`` starts one): tenant
isolation under any SQL a tenant can send, k-anonymous cross-customer results, idempotent
uploads, data policies enforced, and a server that is down losing nothing."""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import replace

import pytest

psycopg = pytest.importorskip("psycopg", reason="the fleet store tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.fleet.audit import read_audit  # noqa: E402
from cellguard.fleet.export import Batch, export_batch  # noqa: E402
from cellguard.fleet.outbox import Outbox  # noqa: E402
from cellguard.fleet.policy import DataPolicy  # noqa: E402
from cellguard.fleet.push import push  # noqa: E402
from cellguard.fleet.signature import Signature  # noqa: E402
from cellguard.fleet.store import (FleetStore, RefusedAggregate, StoreError, StoreUnavailable,  # noqa: E402
                                   TenantStore)
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

TODAY = dt.datetime.now(dt.timezone.utc).date()
DOWN = "host=127.0.0.1 port=1 dbname=x user=x password=x"  # nothing listens on port 1
KEY = b"site-secret-of-the-tests"  # the site key signature ids are keyed with (site_key.py)


def _server() -> str:
    return admin_dsn_or_skip()


def sig(tenant: str, site: str, cause: str, effects: dict, model: str = "arm5", day: dt.date = TODAY) -> Signature:
    return Signature(tenant, site, day.isoformat(), cause, 0.8, model, "arm-pick-place", effects, 7, 1,
                     "pv-" + tenant, "cal-" + tenant, "0.1.0")


def site_sigs(tenant: str, site: str) -> list[Signature]:
    return [sig(tenant, site, "friction", {"current_rms.elbow": 6.0 + len(site), "tracking_rms.elbow": 1.2}),
            sig(tenant, site, "fixture_shift", {"part_seen_x_mm": 11.0, "grasp_tcp_x_mm": 5.0 + len(site)}),
            sig(tenant, site, "servo", {"tracking_rms.shoulder_lift": 9.0, "current_rms.shoulder_lift": 0.5})]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    store = FleetStore(_server(), store_name("fleet"))
    store.install(reset=True)
    dsns = {t: store.add_tenant(t) for t in ("ta", "tb", "tc", "td")}
    for tenant, sites in (("ta", ("sa1", "sa2")), ("tb", ("sb1",)), ("tc", ("sc1",))):
        for site in sites:
            batch = export_batch(site_sigs(tenant, site), DataPolicy(tenant, site), key=KEY)
            assert TenantStore(dsns[tenant]).push(batch) == (3, 0)
    return store, dsns


def count(store: FleetStore, where: str = "true") -> int:
    with store.admin() as con:
        return con.execute(f"SELECT count(*) FROM fleet.signatures WHERE {where}").fetchone()[0]


def as_tenant(dsn: str, sql: str):
    """Run ``sql`` as the tenant, then read what the same session sees; (rows of sql | error, tenants seen)."""
    with psycopg.connect(dsn, autocommit=True) as con:
        try:
            cur = con.execute(sql)
            result = cur.fetchall() if cur.description else cur.rowcount
        except psycopg.Error as exc:
            result = exc
        seen = {r[0] for r in con.execute("SELECT tenant_id FROM fleet.signatures").fetchall()}
        seen |= {r[0] for r in con.execute("SELECT tenant_id FROM fleet.effects").fetchall()}
    return result, seen


@pytest.mark.parametrize("sql", [
    "SELECT tenant_id FROM fleet.signatures WHERE tenant_id = 'tb'",
    "SELECT tenant_id FROM fleet.signatures WHERE tenant_id <> 'ta' OR true",
    "SELECT tenant_id FROM fleet.signatures WHERE 1 = 1 UNION ALL SELECT tenant_id FROM fleet.effects",
    "SELECT tenant_id FROM fleet.signatures s WHERE EXISTS (SELECT 1 FROM fleet.effects e WHERE e.tenant_id = 'tb')",
    "SELECT tenant_id FROM fleet.signatures WHERE fleet.session_tenant() IS NOT NULL OR tenant_id = 'tb'",
    "WITH x AS (SELECT * FROM fleet.signatures) SELECT tenant_id FROM x WHERE tenant_id IN ('tb', 'tc')",
])
def test_crafted_where_clauses_read_only_own_rows(fleet, sql):
    _, dsns = fleet
    rows, seen = as_tenant(dsns["ta"], sql)
    assert not isinstance(rows, Exception), rows
    assert {r[0] for r in rows} <= {"ta"} and seen == {"ta"}


@pytest.mark.parametrize("sql", [
    "SET app.tenant_id = 'tb'",
    "SELECT set_config('app.tenant_id', 'tb', false)",
    "SET ROLE {db}_t_tb",
    "SET ROLE {db}_owner",
    "SET ROLE {db}_agg",
    "SET ROLE {db}_app",
    "SET SESSION AUTHORIZATION {db}_t_tb",
    "ALTER TABLE fleet.signatures DISABLE ROW LEVEL SECURITY",
    "ALTER TABLE fleet.signatures NO FORCE ROW LEVEL SECURITY",
    "DROP POLICY own_rows ON fleet.signatures",
    "CREATE POLICY mine ON fleet.signatures USING (true)",
    "ALTER ROLE {db}_t_ta BYPASSRLS",
    "GRANT {db}_agg TO {db}_t_ta",
    "CREATE OR REPLACE FUNCTION fleet.session_tenant() RETURNS text LANGUAGE sql AS $$ SELECT 'tb' $$",
    "CREATE FUNCTION public.peek() RETURNS text LANGUAGE sql AS $$ SELECT 'tb' $$",
    "UPDATE fleet.tenants SET role_name = '{db}_t_ta' WHERE tenant_id = 'tb'",
    "INSERT INTO fleet.tenants VALUES ('tb2', '{db}_t_ta')",
    "SELECT * FROM fleet.tenants",
    "UPDATE fleet.settings SET min_customers = 1",
    "SELECT * FROM fleet.q_frequency(1)",
])
def test_set_and_ddl_attempts_do_not_widen_what_a_tenant_sees(fleet, sql):
    store, dsns = fleet
    sql = sql.format(db=store.database)
    result, seen = as_tenant(dsns["ta"], sql)
    assert seen == {"ta"}
    if sql.startswith(("SET app.", "SELECT set_config", f"SET ROLE {store.app}")):
        return  # accepted, and harmless: no policy reads a setting or current_user
    assert isinstance(result, psycopg.Error), f"{sql!r} was accepted: {result!r}"
    with store.admin() as con:
        assert con.execute("SELECT min_customers FROM fleet.settings").fetchone()[0] >= 2
        assert con.execute("SELECT role_name FROM fleet.tenants WHERE tenant_id = 'tb'").fetchone()[0] \
            == store.tenant_role("tb")


def test_row_security_off_makes_reads_fail_not_bypass(fleet):
    _, dsns = fleet
    with psycopg.connect(dsns["ta"], autocommit=True) as con:
        con.execute("SET row_security = off")
        with pytest.raises(psycopg.errors.InsufficientPrivilege, match="row-level security"):
            con.execute("SELECT count(*) FROM fleet.signatures")


def test_cannot_update_or_delete_or_insert_another_tenants_rows(fleet):
    store, dsns = fleet
    before = count(store, "tenant_id = 'tb'")
    result, _ = as_tenant(dsns["ta"], "UPDATE fleet.signatures SET cause = 'x' WHERE tenant_id = 'tb'")
    assert isinstance(result, psycopg.errors.InsufficientPrivilege)
    deleted, _ = as_tenant(dsns["ta"], "DELETE FROM fleet.signatures WHERE tenant_id = 'tb' OR true "
                                       "AND site_id = 'nonexistent'")
    assert isinstance(deleted, psycopg.errors.InsufficientPrivilege)  # tenants delete through fleet.forget_site
    deleted, _ = as_tenant(dsns["ta"], "SELECT fleet.forget_site('sb1', '9999-12-31', '9999-12')")
    assert deleted == [(0,)]  # sb1 is tb's
    with store.admin() as con:
        theirs = con.execute("SELECT signature_id FROM fleet.signatures WHERE tenant_id = 'tb' LIMIT 1").fetchone()[0]
    deleted, _ = as_tenant(dsns["ta"], f"SELECT fleet.drop_signature('{theirs}')")
    assert deleted == [(0,)]  # tb's id, named by ta: nothing deleted
    result, _ = as_tenant(dsns["ta"], "INSERT INTO fleet.signatures (signature_id, tenant_id, site_id, created_date,"
                                      " cause, schema_version) VALUES ('x', 'tb', 'sb1', current_date, 'servo', 1)")
    assert isinstance(result, psycopg.errors.InsufficientPrivilege)  # row-level security's WITH CHECK
    assert count(store, "tenant_id = 'tb'") == before == 3
    with store.admin() as con:
        assert con.execute("SELECT count(*) FROM fleet.effects WHERE tenant_id = 'tb'").fetchone()[0] == 6


def test_statistics_do_not_leak_other_tenants_values(fleet):
    store, dsns = fleet
    with store.admin() as con:
        con.execute("ANALYZE fleet.signatures")
        con.commit()
    rows, _ = as_tenant(dsns["ta"], "SELECT most_common_vals::text FROM pg_stats WHERE tablename = 'signatures'")
    assert rows == []


def test_cross_customer_aggregate_under_k_customers_is_refused(fleet):
    store, dsns = fleet
    with pytest.raises(RefusedAggregate, match="^cross-customer query frequency refused: signatures from fewer "
                                               "than 5 customers$"):  # not how many: a count under k
        TenantStore(dsns["ta"]).run("frequency", {"k": 5})
    with pytest.raises(RefusedAggregate, match="fewer than 5 customers"):
        TenantStore(dsns["ta"]).run("frequency", {"k": 2})  # the caller cannot go under the store's k
    store.set_min_customers(3)
    try:
        rows = TenantStore(dsns["td"]).run("frequency", {"k": 3})  # td holds none: the 3 customers are others
        assert {r["cause"] for r in rows} == {"friction", "fixture_shift", "servo"}
        assert all(r["customers"] == 3 and r["signatures"] == 4 for r in rows)
        with pytest.raises(RefusedAggregate, match="fewer than 3 customers"):
            TenantStore(dsns["tb"]).run("frequency", {"k": 3})  # tb's own rows count toward no k: 2 others
        with pytest.raises(RefusedAggregate, match="fewer than 4 customers"):
            TenantStore(dsns["td"]).run("fixes", {"k": 4})
    finally:
        store.set_min_customers(5)


def test_own_scope_sees_only_own_rows(fleet):
    _, dsns = fleet
    rows = TenantStore(dsns["ta"]).run("frequency", scope="own")
    assert {(r["cause"], r["signatures"], r["sites"], r["customers"]) for r in rows} == {
        ("friction", 2, 2, 1), ("fixture_shift", 2, 2, 1), ("servo", 2, 2, 1)}


def test_upload_is_idempotent(fleet):
    store, dsns = fleet
    batch = export_batch(site_sigs("tc", "sc2"), DataPolicy("tc", "sc2"), key=KEY)
    assert TenantStore(dsns["tc"]).push(batch) == (3, 0)
    assert TenantStore(dsns["tc"]).push(batch) == (0, 3)
    assert count(store, "site_id = 'sc2'") == 3


def test_a_batch_under_another_tenants_name_is_refused(fleet):
    _, dsns = fleet
    batch = export_batch(site_sigs("tb", "sb9"), DataPolicy("tb", "sb9"), key=KEY)
    with pytest.raises(StoreError, match="refused the batch of tenant tb"):
        TenantStore(dsns["ta"]).push(batch)


def test_withheld_fields_never_reach_the_store(fleet, tmp_path):
    store, dsns = fleet
    policy = DataPolicy("td", "sd1", withheld=("policy_version", "calibration_version", "effects", "robot_model"))
    result = push(site_sigs("td", "sd1"), policy, tmp_path, TenantStore(dsns["td"]))
    assert (result.new_rows, result.queued) == (3, 0)
    with store.admin() as con:
        rows = con.execute("SELECT policy_version, calibration_version, robot_model FROM fleet.signatures "
                           "WHERE tenant_id = 'td'").fetchall()
        assert rows == [(None, None, None)] * 3
        assert con.execute("SELECT count(*) FROM fleet.effects WHERE tenant_id = 'td'").fetchone()[0] == 0
        con.execute("DELETE FROM fleet.signatures WHERE tenant_id = 'td'")  # td stays a non-customer below


def test_nothing_policy_sends_nothing(fleet, tmp_path):
    store, dsns = fleet
    result = push(site_sigs("td", "sd2"), DataPolicy("td", "sd2", export="nothing"), tmp_path, TenantStore(dsns["td"]))
    assert (result.batch.rows, result.sent_batches, result.queued) == (0, 0, 0)
    assert count(store, "tenant_id = 'td'") == 0
    (entry,) = read_audit(tmp_path)
    assert (entry["what"], entry["rows"], entry["withheld_rows"]) == ("nothing", 0, 3)


def test_aggregates_only_sends_counts_not_signatures(fleet, tmp_path):
    store, dsns = fleet
    many = [s for d in range(4) for s in site_sigs("td", "sd3") for s in [
        Signature(**{**s.__dict__, "created_date": (TODAY - dt.timedelta(days=d)).isoformat()})]]
    policy = DataPolicy("td", "sd3", export="aggregates_only", min_group_size=4)
    push(many, policy, tmp_path, TenantStore(dsns["td"]))
    with store.admin() as con:
        assert con.execute("SELECT count(*) FROM fleet.signatures WHERE tenant_id = 'td'").fetchone()[0] == 0
        counts = con.execute("SELECT sum(signatures) FROM fleet.aggregates WHERE tenant_id = 'td'").fetchone()[0]
    assert counts == sum(r["signatures"] for r in export_batch(many, policy, key=KEY).aggregates) > 0


def test_server_down_queues_and_the_next_push_sends(fleet, tmp_path):
    store, dsns = fleet
    policy = DataPolicy("tc", "sc3")
    with pytest.raises(StoreUnavailable, match="fleet store 127.0.0.1:1/x unreachable"):
        TenantStore(DOWN).push(Batch("tc", "sc3", "v", "signatures"))
    first = push(site_sigs("tc", "sc3"), policy, tmp_path, TenantStore(DOWN))
    assert first.unavailable and "password" not in first.unavailable and first.queued == 1
    assert count(store, "site_id = 'sc3'") == 0
    second = push([], policy, tmp_path, TenantStore(dsns["tc"]))  # nothing new; the queued batch goes
    assert (second.sent_batches, second.new_rows, second.queued) == (1, 3, 0)
    assert count(store, "site_id = 'sc3'") == 3
    assert [e["status"] for e in read_audit(tmp_path)] == ["queued", "nothing", "sent"]
    assert Outbox(tmp_path).pending() == []


def test_similar_finds_own_other_sites_only(fleet):
    from cellguard.fleet.similar import similar

    _, dsns = fleet
    probe = sig("ta", "sa1", "friction", {"current_rms.elbow": 7.0, "tracking_rms.elbow": 1.0})
    found = similar(TenantStore(dsns["ta"]), probe, limit=3)
    assert found and {n.site_id for n in found} == {"sa2"}
    assert found[0].cause == "friction" and found[0].similarity > 0.95
    assert all(f["scope"] == "own" for n in found for f in n.fixes)  # 3 customers < k: no fleet figures


def test_fleet_advice_counts_what_fixed_a_cause_over_k_customers_only():
    from cellguard.fleet.advice import fleet_fixes

    store = FleetStore(_server(), store_name("advice"))
    store.install(reset=True)
    dsns = {t: store.add_tenant(t) for t in ("ta", "tb", "tc", "td")}
    for tenant, fixed in (("ta", True), ("tb", True), ("tc", False)):
        slip = replace(sig(tenant, "s1", "tool_slip", {"grasp_offset_x_mm": 4.0}), recovery="retry_grasp",
                       recovery_outcome="success" if fixed else "failed")
        TenantStore(dsns[tenant]).push(export_batch([slip], DataPolicy(tenant, "s1"), key=KEY))
    assert fleet_fixes(TenantStore(dsns["td"])) == []  # 3 customers: under the store's k of 5, no advice
    assert fleet_fixes(TenantStore(dsns["td"]), k=3) == []  # nor can the caller ask for less than the store's k
    store.set_min_customers(3)
    rows = fleet_fixes(TenantStore(dsns["td"]), k=3)
    assert rows == [{"cause": "tool_slip", "recovery": "retry_grasp", "fixed": 2, "tried": 3, "customers": 3,
                     "scope": "fleet"}]


@pytest.mark.parametrize("dsn", ["garbage=== password=s3cret-pw", "host=x password s3cret-pw",
                                 "postgresql://u:s3cret-pw@[bad"])
def test_a_malformed_dsn_is_refused_without_echoing_it(dsn):
    from cellguard.errors import ConfigError
    from cellguard.fleet.store import connect

    for call in (lambda: TenantStore(dsn), lambda: connect(dsn), lambda: FleetStore(dsn)):
        with pytest.raises(ConfigError, match="DSN .*malformed") as caught:
            call()
        assert "s3cret" not in str(caught.value) and "\n" not in str(caught.value)


def test_an_unreachable_store_gives_the_first_line_of_the_reason():
    with pytest.raises(StoreUnavailable) as caught:
        TenantStore(DOWN).push(Batch("tc", "sc3", "v", "signatures"))
    message = str(caught.value)
    assert "Connection refused" in message and "\t" not in message and "Is the server running" not in message


HIJACK = """
CREATE TEMP VIEW signatures WITH (security_invoker = true) AS
  SELECT s.signature_id, 'fake' || g AS tenant_id, s.site_id, s.created_date,
         s.tenant_id || '|' || s.cause AS cause, s.robot_model, s.cell_type, s.onset_cycle,
         s.detection_delay_cycles, s.policy_version, s.calibration_version, s.cellguard_version, s.recovery,
         s.recovery_outcome, s.schema_version
  FROM fleet.signatures s CROSS JOIN generate_series(1, 5) g;
GRANT SELECT ON signatures TO {agg};
"""


def test_a_temporary_view_cannot_stand_in_for_the_table_of_a_cross_customer_function(fleet):
    store, dsns = fleet
    store.set_min_customers(2)  # the 2 customers besides ta pass k, so the function body runs
    try:
        honest = TenantStore(dsns["ta"]).run("frequency", {"k": 2})
        hijack = HIJACK.format(agg=store.agg)
        made, _ = as_tenant(dsns["ta"], hijack)
        assert isinstance(made, psycopg.errors.InsufficientPrivilege)  # tenants create no temporary object
        with store.admin() as con:  # and were one made, the function still reads fleet.signatures
            con.execute(f"GRANT TEMPORARY ON DATABASE {store.database} TO {store.app}")
            con.commit()
        with psycopg.connect(dsns["ta"], autocommit=True) as con:
            con.execute(hijack)
            rows = con.execute("SELECT cause, customers FROM fleet.q_frequency(2)").fetchall()
        assert sorted(rows) == sorted((r["cause"], r["customers"]) for r in honest)
        assert not any("|" in cause for cause, _ in rows)
        store.install()  # an existing store brought up to date: the grant is gone again
        with store.admin() as con:
            assert not con.execute("SELECT has_database_privilege(%s, %s, 'TEMPORARY')",
                                   (store.tenant_role("ta"), store.database)).fetchone()[0]
    finally:
        store.set_min_customers(5)


def test_resetting_a_store_drops_its_own_roles_only():
    other = FleetStore(_server(), store_name("reset_x"))  # its name starts with the reset store's
    other.install(reset=True)
    other.add_tenant("ta")
    FleetStore(_server(), store_name("reset")).install(reset=True)
    with other.admin() as con:
        roles = {r[0] for r in con.execute("SELECT rolname FROM pg_roles WHERE starts_with(rolname, %s)",
                                           (other.database,))}
    assert roles == {other.owner, other.agg, other.app, other.tenant_role("ta")}


def test_similar_leaves_out_a_non_finite_effect_already_in_the_store(fleet):
    from cellguard.fleet.similar import similar

    store, dsns = fleet
    with store.admin() as con:  # written before signatures were checked
        con.execute("INSERT INTO fleet.signatures (signature_id, tenant_id, site_id, created_date, cause, robot_model, "
                    "schema_version) VALUES ('nan1', 'ta', 'sa9', current_date, 'odd', 'arm5', 1)")
        con.execute("INSERT INTO fleet.effects VALUES ('ta', 'nan1', 'current_rms.elbow', 'NaN'), "
                    "('ta', 'nan1', 'tracking_rms.elbow', 'Infinity')")
        con.commit()
    try:
        probe = sig("ta", "sa1", "friction", {"current_rms.elbow": 7.0, "tracking_rms.elbow": 1.0})
        found = similar(TenantStore(dsns["ta"]), probe, limit=5)
        assert found and "nan1" not in {n.signature_id for n in found}
        assert found[0].cause == "friction" and all(math.isfinite(n.similarity) for n in found)
    finally:
        with store.admin() as con:
            con.execute("DELETE FROM fleet.signatures WHERE signature_id = 'nan1'")


@pytest.mark.parametrize("sql", [
    "SELECT n_tup_ins FROM pg_stat_user_tables",
    "SELECT n_tup_ins FROM pg_stat_all_tables",
    "SELECT n_tup_ins FROM pg_stat_xact_user_tables",
    "SELECT heap_blks_read FROM pg_statio_user_tables",
    "SELECT usename FROM pg_stat_activity",
    "SELECT rolname FROM pg_roles",
    "SELECT usename FROM pg_user",
    "SELECT reltuples FROM pg_class",
    "SELECT pg_relation_size('fleet.signatures')",
    "SELECT pg_total_relation_size('fleet.signatures')",
    "SELECT pg_stat_get_tuples_inserted('fleet.signatures'::regclass)",
    "SELECT count(*) FROM pg_locks",
])
def test_server_statistics_sizes_and_roles_are_not_for_tenants(fleet, sql):
    _, dsns = fleet
    result, _ = as_tenant(dsns["ta"], sql)
    assert isinstance(result, psycopg.errors.InsufficientPrivilege), f"{sql!r} answered {result!r}"


@pytest.mark.parametrize("mode", ["ACCESS EXCLUSIVE", "EXCLUSIVE", "SHARE", "SHARE ROW EXCLUSIVE"])
def test_a_tenant_cannot_lock_out_the_others(fleet, mode):
    _, dsns = fleet
    for table in ("signatures", "effects", "aggregates"):
        with psycopg.connect(dsns["ta"]) as con, pytest.raises(psycopg.errors.InsufficientPrivilege):
            con.execute(f"LOCK TABLE fleet.{table} IN {mode} MODE")


def test_a_lock_held_elsewhere_ends_a_push_and_a_query_in_bounded_time(fleet, tmp_path):
    store, dsns = fleet
    policy = DataPolicy("tc", "sc-lock")
    with store.admin() as holder:  # what a tenant could do before it lost DELETE; the operator still can
        holder.execute("LOCK TABLE fleet.signatures IN ACCESS EXCLUSIVE MODE")
        tenant = TenantStore(dsns["tc"], lock_timeout_s=1)
        with pytest.raises(StoreUnavailable, match=r"busy: gave up after its lock_timeout 1 s") as info:
            tenant.run("frequency", scope="own")
        assert "\n" not in str(info.value)
        result = push(site_sigs("tc", "sc-lock"), policy, tmp_path, tenant)
        assert "lock_timeout" in result.unavailable and result.queued == 1 and result.sent_batches == 0
        holder.rollback()
    again = push([], policy, tmp_path, TenantStore(dsns["tc"]))
    assert (again.sent_batches, again.new_rows, again.queued) == (1, 3, 0)
