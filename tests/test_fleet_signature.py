"""Fault signatures, data policies and their enforcement at export, the audit log and the outbox.
No server needed: these run everywhere."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import stat

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.fleet.audit import append_audit, read_audit
from cellguard.fleet.export import Batch, export_batch, refusal
from cellguard.fleet.outbox import Outbox
from cellguard.fleet.policy import KEYS, DataPolicy, PolicyError, load_policy, parse_policy
from cellguard.fleet.signature import (SCHEMA_VERSION, WITHHOLDABLE, Signature, SignatureError, from_dict,
                                       row_from_dict, signatures_of)

TODAY = dt.date(2026, 11, 23)
CONTEXT = {"site": "Acme Plant Lyon", "cell_id": "line-3", "cell": "arm-pick-place",
           "policy": {"source": "scripted", "sha256": "ab" * 32},
           "embodiment": {"robot": "cellguard-arm5", "version": 1, "sha256": "cd" * 32},
           "camera_calibration": [0.0, 0.0, 1.5], "software": {"cellguard": "0.1.0"}}
DIAGNOSIS = {"findings": [{"cause": "fixture_shift", "cycle": 8, "confidence": 0.92, "evidence": ["moved +4.0 mm"],
                           "signals": ["part_seen_x_mm", "grasp_tcp_x_mm"]},
                          {"cause": "friction", "cycle": 9, "confidence": 0.7, "evidence": [],
                           "signals": ["current_rms.elbow"], "joints": ["elbow"]}],
             "changes": [{"signal": "part_seen_x_mm", "onset": 7, "alarm_cycle": 8, "baseline": 412.25,
                          "last_good": 412.31, "first_faulted": 416.27, "at_alarm": 416.21, "change": 3.96,
                          "scales": 11.32},
                         {"signal": "grasp_tcp_x_mm", "onset": 7, "alarm_cycle": 9, "baseline": 398.5,
                          "last_good": 398.6, "first_faulted": 401.5, "at_alarm": 401.55, "change": 3.05, "scales": 5.1},
                         {"signal": "current_rms.elbow", "onset": 6, "alarm_cycle": 9, "baseline": 0.731,
                          "last_good": 0.74, "first_faulted": 0.95, "at_alarm": 0.97, "change": 0.239, "scales": 7.9}]}
KEY = b"site-secret-of-the-tests"  # the site key signature ids are keyed with (site_key.py)


def sigs(tenant="t-acme", site="s-01", day=TODAY):
    return signatures_of(DIAGNOSIS, CONTEXT, tenant, site, day)


def test_one_signature_per_finding_with_effect_sizes_and_no_raw_values_or_names():
    a, b = sigs()
    assert (a.cause, b.cause) == ("fixture_shift", "friction")
    assert a.effects == {"part_seen_x_mm": 11.32, "grasp_tcp_x_mm": 5.1}
    assert (a.onset_cycle, a.detection_delay_cycles) == (7, 1)  # onset 7, first alarm of its signals 8
    assert (b.onset_cycle, b.detection_delay_cycles) == (6, 3)
    assert a.robot_model == "cellguard-arm5" and a.cell_type == "arm-pick-place" and a.cellguard_version == "0.1.0"
    assert len(a.policy_version) == 12 and len(a.calibration_version) == 12
    assert a.recovery is None and a.recovery_outcome is None
    text = json.dumps([s.to_dict() for s in (a, b)])
    for raw in ("412.25", "416.21", "398.5", "0.731", "0.97", "3.96", "Acme", "Lyon", "line-3", "moved"):
        assert raw not in text  # no raw feature values, no site or customer names, no evidence text


def test_signature_id_is_keyed_with_the_site_secret():
    a = sigs()[0]
    assert a.signature_id(KEY) == sigs()[0].signature_id(KEY)  # the same finding at the same site: the same row
    assert a.signature_id(KEY) != sigs(site="s-02")[0].signature_id(KEY)
    assert a.signature_id(KEY) != a.signature_id(b"another site's key")


def test_withheld_fields_cannot_be_recovered_from_the_id():
    """The attack found: hash candidate values (those other rows show openly) until one gives the id."""
    sig = sigs()[0]
    policy = DataPolicy("t-acme", "s-01", withheld=("policy_version", "confidence", "onset_cycle"))
    row = export_batch([sig], policy, TODAY, key=KEY).signatures[0]
    assert row["policy_version"] is None and row["confidence"] is None and row["onset_cycle"] is None
    body = {k: v for k, v in row.items() if k != "signature_id"}
    tried = set()
    for pv in (sig.policy_version, "pv-other", None):
        for conf in [i / 100 for i in range(101)] + [sig.confidence]:
            for onset in range(50):
                guess = {**body, "policy_version": pv, "confidence": conf, "onset_cycle": onset}
                text = json.dumps(guess, sort_keys=True, separators=(",", ":"))
                tried.add(hashlib.sha256(text.encode()).hexdigest()[:32])
    assert row["signature_id"] not in tried


def test_newer_schema_version_is_refused_in_one_line():
    raw = sigs()[0].to_dict()
    raw["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(SignatureError, match=r"schema_version: 2 is newer than this cellguard reads") as info:
        from_dict(raw)
    assert "\n" not in str(info.value)


def test_unknown_field_and_malformed_id_are_refused():
    raw = sigs()[0].to_dict()
    with pytest.raises(SignatureError, match="signature.raw_ticks: unknown field"):
        from_dict({**raw, "raw_ticks": [1, 2]})
    with pytest.raises(SignatureError, match="signature.signature_id: expected 32 hex digits"):
        row_from_dict({**raw, "signature_id": "x'; DROP TABLE"})


@settings(max_examples=60, deadline=None)
@given(cause=st.sampled_from(["fixture_shift", "servo", "friction"]),
       effects=st.dictionaries(st.text("abcdefgh_.", min_size=1, max_size=12),
                               st.floats(-1e6, 1e6, allow_nan=False), max_size=6),
       withheld=st.lists(st.sampled_from(WITHHOLDABLE), unique=True, max_size=4))
def test_round_trip_and_withheld_fields_are_empty(cause, effects, withheld):
    sig = Signature("t-a", "s-1", "2026-11-01", cause, 0.5, "arm5", "arm-pick-place", effects, 3, 1, "p" * 12,
                    "c" * 12, "0.1.0")
    assert from_dict(sig.to_dict()) == sig
    policy = DataPolicy("t-a", "s-1", withheld=tuple(withheld))
    row = export_batch([sig], policy, dt.date(2026, 11, 2), key=KEY).signatures[0]
    assert all(row[name] is None for name in withheld)
    assert row_from_dict(row) == row and row["signature_id"] == sig.signature_id(KEY)  # one id whatever is withheld


def test_policy_unknown_key_names_it(tmp_path):
    path = tmp_path / "policy.yaml"
    path.write_text("tenant: t-a\nsite: s-1\nexport: signatures\nshare_raw_records: true\n")
    with pytest.raises(PolicyError, match=r"share_raw_records: unknown key; allowed: " + ", ".join(KEYS)):
        load_policy(path)


@pytest.mark.parametrize("raw, match", [
    ({"tenant": "Acme Corp", "site": "s-1", "export": "nothing"}, "policy.tenant: expected an opaque id"),
    ({"tenant": "t-a", "site": "s-1", "export": "everything"}, "policy.export: 'everything'; allowed"),
    ({"tenant": "t-a", "site": "s-1", "export": "nothing", "min_group_size": 1},
     r"min_group_size: expected an integer 2\.\.1000000"),
    ({"tenant": "t-a", "site": "s-1", "export": "nothing", "withheld": ["cause"]}, "'cause' cannot be withheld"),
    ({"tenant": "t-a", "site": "s-1", "export": "nothing", "retention_days": 0},
     r"retention_days: expected an integer 1\.\.36500"),
    ({"tenant": "t-a"}, "site: required"),
    ({"tenant": "t-a", "site": "s-1"}, r"^policy: export: required, .*: signatures \| aggregates_only \| nothing$"),
])
def test_policy_bad_values_name_the_key(raw, match):
    with pytest.raises(PolicyError, match=match):
        parse_policy(raw)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])  # a shared machine
@given(st.dictionaries(st.sampled_from(KEYS + ("extra", "Tenant", "")),
                       st.one_of(st.none(), st.booleans(), st.integers(-5, 10**7), st.text(max_size=12),
                                 st.lists(st.sampled_from(WITHHOLDABLE + ("cause", "x")), max_size=3)), max_size=7))
def test_policy_parser_accepts_or_names_the_problem(raw):
    try:
        policy = parse_policy(raw)
    except PolicyError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("policy: ")
    else:
        assert policy.export in ("signatures", "aggregates_only", "nothing") and len(policy.version) == 12


@pytest.mark.parametrize("raw", [{"tenant": "t-acme\n", "site": "s-1", "export": "nothing"},
                                 {"tenant": "t-acme", "site": "s-1\n", "export": "nothing"}],
                         ids=["tenant", "site"])
def test_an_id_ending_in_a_newline_is_refused(tmp_path, raw):
    with pytest.raises(PolicyError, match="expected an opaque id"):
        parse_policy(raw)
    path = tmp_path / "p.yaml"
    path.write_text(f"tenant: {json.dumps(raw['tenant'])}\nsite: {json.dumps(raw['site'])}\nexport: nothing\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(path),
                                      "--site-dir", str(tmp_path / "site")])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "expected an opaque id" in result.stderr
    assert not (tmp_path / "site").exists()


def test_a_tenant_or_query_text_ending_in_a_newline_is_refused_on_the_lake_and_in_queries(tmp_path):
    from cellguard.errors import ConfigError
    from cellguard.fleet.lake import tenant_dir
    from cellguard.fleet.queries import QUERIES, render

    with pytest.raises(ConfigError, match="tenant: expected an opaque id"):
        tenant_dir(tmp_path, "t0\n")
    with pytest.raises(ConfigError, match="parameter site must match"):
        render(QUERIES["similar"], {"site": "s-1\n"})


def test_nothing_exports_nothing_and_aggregates_respect_the_group_size():
    many = [s for d in range(6) for s in sigs(day=TODAY - dt.timedelta(days=d))]
    nothing = export_batch(many, DataPolicy("t-acme", "s-01", export="nothing"), TODAY, key=KEY)
    assert nothing.rows == 0 and nothing.signatures == () and nothing.withheld_rows == len(many)
    agg = export_batch(many, DataPolicy("t-acme", "s-01", "aggregates_only", min_group_size=6), TODAY, key=KEY)
    assert agg.signatures == ()
    assert {(r["cause"], r["signatures"]) for r in agg.aggregates} == {("fixture_shift", 6), ("friction", 6)}
    small = export_batch(many[:8], DataPolicy("t-acme", "s-01", "aggregates_only", min_group_size=5), TODAY, key=KEY)
    assert small.aggregates == () and small.withheld_rows == 8  # 4 and 4: under the group size


def test_aggregates_leave_out_what_the_policy_withholds():
    many = [s for d in range(6) for s in sigs(day=TODAY - dt.timedelta(days=d))]
    policy = DataPolicy("t-acme", "s-01", "aggregates_only", min_group_size=6, withheld=("robot_model", "cell_type"))
    batch = export_batch(many, policy, TODAY, key=KEY)
    assert batch.aggregates and all(r["robot_model"] is None and r["cell_type"] is None for r in batch.aggregates)
    assert "cellguard-arm5" not in json.dumps(batch.to_dict()) and "arm-pick-place" not in json.dumps(batch.to_dict())
    assert refusal(batch, policy, TODAY) is None
    open_batch = export_batch(many, DataPolicy("t-acme", "s-01", "aggregates_only", min_group_size=6), TODAY, key=KEY)
    assert refusal(open_batch, policy, TODAY) == "it holds cell_type, robot_model, which the policy withholds"


@pytest.mark.parametrize("value", ["p" * 100_014, "v1\x1b[31m", "v1\n"])
def test_a_queued_batch_with_a_malformed_policy_version_is_refused(value):
    raw = {**export_batch(sigs(), DataPolicy("t-acme", "s-01"), TODAY, key=KEY).to_dict(with_id=False),
           "policy_version": value}
    with pytest.raises(SignatureError, match="batch.policy_version: expected printable text") as info:
        Batch.from_dict(raw)
    assert "\n" not in str(info.value) and len(str(info.value)) < 400


def test_retention_keeps_old_signatures_at_the_site():
    old = sigs(day=TODAY - dt.timedelta(days=40))
    new = sigs()
    batch = export_batch(old + new, DataPolicy("t-acme", "s-01", retention_days=30), TODAY, key=KEY)
    assert {s["created_date"] for s in batch.signatures} == {TODAY.isoformat()} and batch.withheld_rows == 2


def test_a_signature_of_another_site_is_not_sent():
    with pytest.raises(PolicyError, match="is not the policy's t-acme/s-01"):
        export_batch(sigs(site="s-99"), DataPolicy("t-acme", "s-01"), TODAY, key=KEY)


def test_audit_appends_and_outbox_is_idempotent(tmp_path):
    batch = export_batch(sigs(), DataPolicy("t-acme", "s-01"), TODAY, key=KEY)
    box = Outbox(tmp_path)
    box.put(batch)
    box.put(batch)
    (path, queued), = box.pending()
    assert queued == batch and not list(tmp_path.glob("outbox/*.tmp"))
    append_audit(tmp_path, batch, "queued", "nowhere")
    append_audit(tmp_path, Batch("t-acme", "s-01", "v", "nothing"), "nothing", "nowhere")
    entries = read_audit(tmp_path)
    assert [(e["status"], e["rows"]) for e in entries] == [("queued", 2), ("nothing", 0)]
    assert entries[0]["policy_version"] == DataPolicy("t-acme", "s-01").version
    box.done(path)
    assert box.pending() == []


def test_cli_policy_with_unknown_key_is_one_line_exit_2(tmp_path):
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: t-a\nsite: s-1\nsend_everything: yes\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(policy),
                                      "--site-dir", str(tmp_path / "site")])
    assert result.exit_code == 2
    assert result.output.strip().count("\n") == 0 and "send_everything: unknown key" in result.output
    assert not (tmp_path / "site").exists()  # nothing exported, nothing logged


def test_cli_nothing_policy_logs_an_empty_export_without_reading_records(tmp_path):
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: t-a\nsite: s-1\nexport: nothing\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(policy),
                                      "--site-dir", str(tmp_path / "site"), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["rows"] == 0
    (entry,) = read_audit(tmp_path / "site")
    assert (entry["what"], entry["rows"], entry["status"]) == ("nothing", 0, "nothing")
    assert not (tmp_path / "site" / "outbox").exists()


def test_cli_push_with_a_batch_of_a_newer_schema_queued_names_it_and_keeps_it(tmp_path):
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: t-acme\nsite: s-01\nexport: nothing\n")
    newer = export_batch(sigs(), DataPolicy("t-acme", "s-01"), TODAY, key=KEY).to_dict()
    newer["signatures"][0] = {**newer["signatures"][0], "schema_version": SCHEMA_VERSION + 1}
    queued = tmp_path / "site" / "outbox" / "newer.json"  # left by a newer cellguard on this site
    queued.parent.mkdir(parents=True)
    queued.write_text(json.dumps(newer))
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path), "--policy", str(policy),
                                      "--site-dir", str(tmp_path / "site")])
    assert result.exit_code == 1, result.output  # the push itself was done; the queued file needs a person
    (line,) = [ln for ln in result.stderr.splitlines() if "newer.json" in ln]
    assert "newer.json: signature.schema_version: 2 is newer than this cellguard reads" in line
    assert "it stays queued" in line and json.loads(queued.read_text()) == newer  # nothing lost


@pytest.mark.parametrize("field,value", [
    ("confidence", "0.5"), ("confidence", float("nan")), ("confidence", 1e300), ("confidence", True),
    ("effects", {"current_rms.elbow": "1e3"}), ("effects", {"current_rms.elbow": float("inf")}),
    ("effects", {"current_rms.elbow": [1, 2]}), ("effects", {"a\x1b[2J": 1.0}), ("effects", [1.0]),
    ("onset_cycle", "7"), ("onset_cycle", -5), ("detection_delay_cycles", 1.5),
    ("cause", "x\x1b[2J"), ("cause", ""), ("robot_model", "arm\n5"), ("recovery_outcome", "maybe"),
    ("site_id", "S 9"), ("tenant_id", "t-acme\n"), ("created_date", "20261120"), ("created_date", "2026-02-30"),
])
def test_a_mistyped_non_finite_or_unprintable_field_is_refused_naming_it(field, value):
    raw = {**sigs()[0].to_dict(), field: value}
    with pytest.raises(SignatureError, match=rf"^signature\.{field}\b") as caught:
        from_dict(raw)
    assert "\n" not in str(caught.value) and "\x1b" not in str(caught.value)


def test_a_batch_whose_signatures_name_another_site_is_refused():
    raw = export_batch(sigs(), DataPolicy("t-acme", "s-01"), TODAY, key=KEY).to_dict(with_id=False)
    raw["signatures"][1] = {**raw["signatures"][1], "site_id": "s-99"}
    with pytest.raises(SignatureError, match=r"batch.signatures\[1\]: of t-acme/s-99, in a batch of t-acme/s-01"):
        Batch.from_dict(raw)


def test_outbox_files_are_for_the_owner_and_group_only_as_the_audit_log(tmp_path):
    umask = os.umask(0o022)
    try:
        batch = export_batch(sigs(), DataPolicy("t-acme", "s-01"), TODAY, key=KEY)
        path = Outbox(tmp_path).put(batch)
        append_audit(tmp_path, batch, "queued", "nowhere")
    finally:
        os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640 == stat.S_IMODE((tmp_path / "audit.jsonl").stat().st_mode)


def test_a_similar_probe_leaves_the_site_as_its_policy_lets_it():
    """`fleet similar RUN --policy` sent the run's robot model and effects to the store as query parameters even
    under a policy that withheld them."""
    from cellguard.errors import ConfigError
    from cellguard.fleet.similar import as_sent

    sig = sigs()[0]
    assert sig.robot_model and as_sent(sig, ("robot_model",)).robot_model is None
    assert as_sent(sig, ("robot_model",)).effects == sig.effects and as_sent(sig, ()) == sig
    with pytest.raises(ConfigError, match="withholds effects, which `fleet similar` sends"):
        as_sent(sig, ("effects",))
