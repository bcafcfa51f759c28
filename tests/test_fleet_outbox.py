"""The site's outbox and audit log when a file in them is damaged, hostile or not a file: each bad
file is named in one line and kept, the other batches and entries go on, nothing is lost."""

from __future__ import annotations

import datetime as dt
import json
import os
import threading

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError
from cellguard.fleet.audit import append_audit, read_audit
from cellguard.fleet.export import Batch, export_batch
from cellguard.fleet.outbox import Outbox
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature
from cellguard.yaml_file import read_yaml

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY = DataPolicy("t-acme", "s-01")
KEY = b"site-secret-of-the-tests"  # the site key signature ids are keyed with (site_key.py)


def sigs() -> list[Signature]:
    return [Signature("t-acme", "s-01", TODAY.isoformat(), "friction", 0.8, "arm5", "arm-pick-place",
                      {"current_rms.elbow": 6.0}, 7, 1)]


def good_batch() -> Batch:
    return export_batch(sigs(), POLICY, TODAY, key=KEY)


BAD_FILES = {
    "not-json": lambda p: p.write_text("this is not JSON {"),
    "empty-object": lambda p: p.write_text("{}"),
    "a-list": lambda p: p.write_text("[1, 2]"),
    "not-utf8": lambda p: p.write_bytes(b"\xff\xfe\x00{"),
    "dangling-link": lambda p: p.symlink_to(p.parent / "gone.json"),
    "fifo": lambda p: os.mkfifo(p),
    "folder": lambda p: p.mkdir(),
    "signatures-not-a-list": lambda p: p.write_text(json.dumps({**good_batch().to_dict(), "signatures": 3})),
    "bad-aggregate": lambda p: p.write_text(json.dumps({**good_batch().to_dict(with_id=False),
                                                        "export": "aggregates_only", "signatures": [],
                                                        "aggregates": [{"cause": 1}]})),
    "bad-date": lambda p: p.write_text(json.dumps(
        {**good_batch().to_dict(with_id=False),
         "signatures": [{**sigs()[0].to_dict(), "created_date": "2026-99-99"}]})),
    "forged-batch-id": lambda p: p.write_text(json.dumps({**good_batch().to_dict(), "batch_id": "0" * 32})),
}


@pytest.mark.parametrize("kind", sorted(BAD_FILES))
def test_a_bad_outbox_file_is_named_kept_and_the_others_read(tmp_path, kind):
    box = Outbox(tmp_path)
    box.put(good_batch())
    bad = tmp_path / "outbox" / "bad.json"
    BAD_FILES[kind](bad)
    pending = guarded(kind, bad, box.pending)
    assert pending == [(tmp_path / "outbox" / f"{good_batch().batch_id}.json", good_batch())]
    batches, unreadable = box.read()
    assert [b for _, b in batches] == [good_batch()]
    ((path, why),) = unreadable
    assert path == bad and why and "\n" not in why
    assert box.count() == 2


@pytest.mark.parametrize("kind", sorted(BAD_FILES))
def test_cli_push_with_a_bad_outbox_file_and_no_store_names_it_in_one_line(tmp_path, kind):
    site = tmp_path / "site"
    Outbox(site).put(good_batch())
    bad = site / "outbox" / "bad.json"
    BAD_FILES[kind](bad)
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: t-acme\nsite: s-01\nexport: nothing\n")
    args = ["fleet", "push", str(tmp_path), "--policy", str(policy), "--site-dir", str(site), "--json"]
    result = guarded(kind, bad, lambda: CliRunner().invoke(app, args))
    assert result.exit_code == 1, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    (line,) = [ln for ln in result.stderr.splitlines() if "bad.json" in ln]
    assert line.startswith("warning: ") and line.endswith("it stays queued")
    assert json.loads(result.stdout)["queued"] == 2
    assert os.path.lexists(bad) and Outbox(site).pending() == [(site / "outbox" / f"{good_batch().batch_id}.json",
                                                                 good_batch())]


def test_push_without_a_store_reads_past_a_bad_file(tmp_path):
    (tmp_path / "outbox").mkdir()
    (tmp_path / "outbox" / "junk.json").write_text("{}")
    result = push(sigs(), POLICY, tmp_path, None)
    assert result.queued == 2 and len(result.failed) == 1 and "junk.json" in result.failed[0]


# -- F8: the audit log ---------------------------------------------------------------------------------------------


def damaged_log(site) -> None:
    append_audit(site, good_batch(), "queued", "nowhere")
    with open(site / "audit.jsonl", "ab") as f:
        f.write(b"{torn line\n[1, 2]\n" + json.dumps({"status": "sent", "batch_id": 7}).encode() + b"\n\xff\xfe\n")
    append_audit(site, good_batch(), "sent", "127.0.0.1:5432/fleet")


def test_cli_audit_of_a_damaged_log_shows_what_it_can_and_names_each_bad_line(tmp_path):
    damaged_log(tmp_path)
    result = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(tmp_path)])
    assert result.exit_code == 1 and (result.exception is None or isinstance(result.exception, SystemExit))
    shown = " ".join(result.stdout.split())  # the console wraps long lines
    assert "2 entries" in shown and " queued " in shown and " sent " in shown
    bad = result.stderr.splitlines()
    assert [ln.split("audit.jsonl: ")[1].split(":")[0] for ln in bad] == ["line 2", "line 3", "line 4", "line 5"]
    as_json = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(tmp_path), "--json"])
    assert as_json.exit_code == 1 and len(json.loads(as_json.stdout)["entries"]) == 2
    from cellguard.fleet.audit import AuditError, scan_audit

    with pytest.raises(AuditError, match="line 2: not a JSON entry .and 3 more"):
        read_audit(tmp_path)
    entries, damaged = scan_audit(tmp_path)
    assert len(entries) == 2 and len(damaged) == 4


@pytest.mark.parametrize("what", ["file", "missing"])
def test_cli_audit_of_a_site_dir_that_is_not_a_folder_is_one_line_exit_2(tmp_path, what):
    site = tmp_path / "site.yaml"
    if what == "file":
        site.write_text("tenant: t-acme\n")
    result = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and result.stdout == ""
    assert ("not a folder" if what == "file" else "no such folder") in result.stderr


def test_cli_audit_of_a_fifo_log_does_not_block(tmp_path):
    os.mkfifo(tmp_path / "audit.jsonl")
    result = run_with_fifo_guard(tmp_path / "audit.jsonl",
                                 lambda: CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(tmp_path)]))
    assert result.exit_code == 2 and "is a FIFO" in result.stderr


# -- F10: a FIFO as an input file ----------------------------------------------------------------------------------


def run_with_fifo_guard(fifo, call, timeout_s: float = 10.0):
    """``call()``'s result; if it is still blocked on ``fifo`` after ``timeout_s``, open the FIFO's other end
    to release it and fail."""
    out: dict = {}
    worker = threading.Thread(target=lambda: out.setdefault("result", _catch(call)), daemon=True)
    worker.start()
    worker.join(timeout_s)
    if worker.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        worker.join(timeout_s)
        pytest.fail(f"blocked for {timeout_s} s reading the FIFO {fifo}")
    result = out["result"]
    if isinstance(result, BaseException):
        raise result
    return result


def guarded(kind: str, bad, call):
    """``call()``, released and failed if it blocks on ``bad`` when that is a FIFO."""
    return run_with_fifo_guard(bad, call) if kind == "fifo" else call()


def _catch(call):
    try:
        return call()
    except BaseException as exc:  # noqa: BLE001 - handed back to the test's thread
        return exc


@pytest.mark.parametrize("what", ["data policy", "scenario", "action map"])
def test_a_fifo_as_an_input_file_is_refused_without_blocking(tmp_path, what):
    fifo = tmp_path / "input.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match=f"input.yaml: is a FIFO, not a regular {what} file"):
        run_with_fifo_guard(fifo, lambda: read_yaml(fifo, what))


def test_cli_push_with_a_fifo_as_the_policy_is_one_line_exit_2(tmp_path):
    fifo = tmp_path / "policy.yaml"
    os.mkfifo(fifo)
    result = run_with_fifo_guard(fifo, lambda: CliRunner().invoke(
        app, ["fleet", "push", str(tmp_path), "--policy", str(fifo), "--site-dir", str(tmp_path / "site")]))
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "is a FIFO" in result.stderr
    assert not (tmp_path / "site").exists()
