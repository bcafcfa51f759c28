"""`cellguard fleet push/query/similar/audit` end to end: a real run, its record diagnosed, its
signatures pushed to the real PostgreSQL server and a Parquet lake, a server that is down."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

psycopg = pytest.importorskip("psycopg", reason="the fleet CLI tests need psycopg: pip install 'cellguard[fleet]'")

from cellguard.fleet.store import FleetStore  # noqa: E402
from fleet_server import admin_dsn_or_skip, store_name  # noqa: E402

DOWN = "host=127.0.0.1 port=1 dbname=x user=x password=x"


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    dsn = admin_dsn_or_skip()
    root = tmp_path_factory.mktemp("fleetcli")
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 11, "acceptance_cycles": 5, "production_cycles": 4,
                                 "faults": [{"kind": "fixture_shift", "at_cycle": 6, "dx_mm": 5.0, "dy_mm": 1.0}]}),
                 root / "run")
    store = FleetStore(dsn, store_name("cli"))
    store.install(reset=True)
    tenants = {t: store.add_tenant(t) for t in ("ta", "tb")}
    for tenant, site in (("ta", "s1"), ("ta", "s2"), ("tb", "s9")):
        (root / f"{tenant}-{site}.yaml").write_text(f"tenant: {tenant}\nsite: {site}\nexport: signatures\n")
    return root, tenants


def cli(*args, dsn=None):
    result = CliRunner().invoke(app, ["fleet", *map(str, args)], env={"CELLGUARD_FLEET_DSN": dsn} if dsn else None)
    return result


def test_push_is_idempotent_and_lands_in_the_lake(env):
    root, tenants = env
    args = ("push", root / "run", "--policy", root / "ta-s1.yaml", "--site-dir", root / "site1", "--lake", root / "lake",
            "--json")
    first = json.loads(cli(*args, dsn=tenants["ta"]).stdout)
    assert first["rows"] >= 1 and first["new_rows"] == first["rows"] and first["queued"] == 0
    again = json.loads(cli(*args, dsn=tenants["ta"]).stdout)
    assert (again["new_rows"], again["duplicate_rows"]) == (0, first["rows"])
    out = cli("query", "frequency", "--lake", root / "lake", "--k", "1", "--json")
    assert out.exit_code == 0, out.output
    rows = json.loads(out.stdout)["rows"]
    assert sum(r["signatures"] for r in rows) == first["rows"]  # the retry replaced its file, no duplicate
    assert "fixture_shift" in {r["cause"] for r in rows}
    own = cli("query", "frequency", "--lake", root / "lake", "--tenant", "ta", "--scope", "own", "--json")
    assert own.exit_code == 0 and json.loads(own.stdout)["rows"] == rows  # the lake holds ta's rows only
    refused = cli("query", "frequency", "--lake", root / "lake", "--tenant", "ta", "--k", "1")
    assert refused.exit_code == 2 and "fewer than 5 customers" in refused.output and "Traceback" not in refused.output
    audit = json.loads(cli("audit", "--site-dir", root / "site1", "--json").stdout)["entries"]
    assert [e["status"] for e in audit] == ["queued", "sent", "queued", "duplicate"]


def test_similar_from_a_folder_and_by_id_within_the_callers_rights(env):
    root, tenants = env
    for tenant, site in (("ta", "s2"), ("tb", "s9")):
        r = cli("push", root / "run", "--policy", root / f"{tenant}-{site}.yaml", "--site-dir", root / site,
                dsn=tenants[tenant])
        assert r.exit_code == 0, r.output
    out = cli("similar", root / "run", "--policy", root / "ta-s1.yaml", "--site-dir", root / "s1-similar", "--json",
              dsn=tenants["ta"])  # its probes are logged there (not in ./cellguard-fleet)
    assert out.exit_code == 0, out.output
    findings = json.loads(out.stdout)["findings"]
    top = findings[0]["neighbours"]
    assert top and top[0]["site_id"] == "s2" and top[0]["similarity"] > 0.999  # same run at ta's other site
    assert all(n["site_id"] == "s2" for f in findings for n in f["neighbours"])  # never tb's s9
    with psycopg.connect(tenants["tb"]) as con:
        theirs = con.execute("SELECT signature_id FROM fleet.signatures").fetchone()[0]
    refused = cli("similar", theirs, dsn=tenants["ta"])
    assert refused.exit_code == 2 and "no such signature among yours" in refused.output
    mine = cli("similar", top[0]["signature_id"], dsn=tenants["ta"])
    assert mine.exit_code == 0 and "similar signature" in mine.output


def test_cross_customer_query_under_k_is_one_line_exit_2(env):
    _, tenants = env
    out = cli("query", "frequency", dsn=tenants["ta"])
    assert out.exit_code == 2
    assert out.output.strip() == "error: cross-customer query frequency refused: signatures from fewer than 5 customers"


def test_server_down_keeps_the_batch_and_says_so(env):
    root, tenants = env
    args = ("push", root / "run", "--policy", root / "ta-s1.yaml", "--site-dir", root / "down")
    out = cli(*args, dsn=DOWN)
    assert out.exit_code == 0
    lines = out.stderr.strip().splitlines()
    assert lines[1].startswith(f"note: {root / 'down' / 'site.key'}: a new site key") and len(lines) == 2
    line = lines[0]
    assert "fleet store 127.0.0.1:1/x unreachable" in line and "1 batch(es) kept in" in line
    assert "password" not in out.stderr
    assert len(list((root / "down" / "outbox").glob("*.json"))) == 1
    back = cli(*args[:-2], "--site-dir", root / "down", "--json", dsn=tenants["ta"])
    assert json.loads(back.stdout)["queued"] == 0
    assert not list((root / "down" / "outbox").glob("*.json"))


def test_diagnose_with_the_fleet_store_down_warns_and_still_diagnoses(env):
    root, _ = env
    result = CliRunner().invoke(app, ["diagnose", str(root / "run"), "--json"], env={"CELLGUARD_FLEET_DSN": DOWN})
    assert result.exit_code == 0, result.output
    assert "no advice from the fleet" in result.stderr and "unreachable" in result.stderr
    assert "fixture_shift" in {f["cause"] for f in json.loads(result.stdout)["findings"]}
    refused = CliRunner().invoke(app, ["diagnose", str(root / "run"), "--fleet"], env={"CELLGUARD_FLEET_DSN": ""})
    assert refused.exit_code == 2 and "CELLGUARD_FLEET_DSN" in refused.output


@pytest.mark.parametrize("dsn", ["garbage=== password=s3cret-pw", "postgresql://u:s3cret-pw@[bad"],
                         ids=["key-value", "uri"])
def test_a_malformed_dsn_is_one_line_exit_2_that_never_shows_it(env, dsn):
    root, _ = env
    results = [CliRunner().invoke(app, ["diagnose", str(root / "run"), "--fleet"], env={"CELLGUARD_FLEET_DSN": dsn}),
               cli("query", "frequency", "--store", dsn),
               cli("push", root / "run", "--policy", root / "ta-s1.yaml", "--site-dir", root / "malformed", dsn=dsn)]
    for result in results:
        assert result.exit_code == 2, result.output
        assert result.exception is None or isinstance(result.exception, SystemExit)
        assert result.stderr.count("\n") == 1 and "DSN" in result.stderr and "malformed" in result.stderr
        assert "s3cret" not in result.output and "Traceback" not in result.output
    assert not (root / "malformed").exists()  # refused before anything was queued


def test_text_a_store_holds_is_printed_with_control_characters_escaped(env):
    _, tenants = env
    store = FleetStore(admin_dsn_or_skip(), store_name("cli"))
    with store.admin() as con:  # rows written before text was checked: a cause that clears the screen
        con.execute("INSERT INTO fleet.signatures (signature_id, tenant_id, site_id, created_date, cause, robot_model, "
                    "schema_version) VALUES ('esc-probe', 'ta', 's7', current_date, 'probe', 'arm5', 1), "
                    "('esc-near', 'ta', 's8', current_date, %s, 'arm5', 1)", ("x\x1b[2J\x1b]0;owned\x07",))
        con.execute("INSERT INTO fleet.effects VALUES ('ta', 'esc-probe', 'f', 2.0), ('ta', 'esc-near', 'f', 2.0)")
    try:
        for out in (cli("similar", "esc-probe", dsn=tenants["ta"]),
                    cli("query", "frequency", "--scope", "own", dsn=tenants["ta"])):
            assert out.exit_code == 0, out.output
            assert "\x1b" not in out.stdout and "\x07" not in out.stdout and "x\\x1b[2J" in out.stdout
    finally:
        with store.admin() as con:
            con.execute("DELETE FROM fleet.signatures WHERE signature_id LIKE 'esc-%'")


def test_a_push_with_a_lake_and_no_store_says_nothing_landed(env):
    """The lake takes what the store took: with no store (or one that is down) a push queued its batch and said
    nothing of the lake given, read as "the lake gets them"."""
    root, _ = env
    lake = root / "lake-alone"
    for dsn, site in ((None, "alone"), (DOWN, "alone-down")):
        out = CliRunner().invoke(app, ["fleet", "push", str(root / "run"), "--policy", str(root / "ta-s1.yaml"),
                                       "--site-dir", str(root / site), "--lake", str(lake)],
                                 env={"CELLGUARD_FLEET_DSN": dsn})  # None: no store, whatever this shell has
        assert out.exit_code == 0, out.output
        assert f"kept in {root / site / 'outbox'}" in out.stderr and \
            f"nothing landed in {lake}: it takes what the store took" in out.stderr, out.stderr
        assert not lake.exists()
