"""Every command that writes (record export, to-lerobot, recover, report) leaves records and run folders alone,
refuses bad outputs and inputs with one line, and prints the paths it was given as they are."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cli_util import one_error
from mcap.writer import CompressionType, Writer
from run_copies import recorded, run  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.record.schemas import CHANNELS
from cellguard.record.writer import PROFILE

runner = CliRunner()


def digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def cli(*args) -> subprocess.CompletedProcess:
    """In a process of its own, so that a command that blocks is stopped (and fails the test) after 60 s."""
    return subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", *map(str, args)],
                          capture_output=True, text=True, timeout=60)


def _part(run: Path) -> Path:
    return next((run / "index" / "cycles").glob("day=*/*.parquet"))


@pytest.mark.parametrize("command, target", [
    (["report"], "record.mcap"), (["report"], "summary.json"), (["report"], "baseline-copy.html"),
    (["record", "export"], "summary.json"), (["record", "export"], "PART"),
    (["record", "to-lerobot"], "record.mcap"), (["record", "to-lerobot"], "dataset"),
    (["record", "recover"], "recovered"),
])
def test_no_output_lands_in_a_run_folder(run, command, target):
    before = digests(run)
    output = _part(run) if target == "PART" else run / target
    line = one_error(runner.invoke(app, [*command, str(run), "-o", str(output)]))
    assert "never overwrites a record" in line and str(output) in line
    assert digests(run) == before


def test_no_output_lands_in_another_run_folder_or_through_a_link(run, tmp_path):
    before = digests(run)
    other = tmp_path / "other"
    other.mkdir()
    (other / "record.mcap").write_bytes((run / "record.mcap").read_bytes())
    (tmp_path / "link.csv").symlink_to(run / "summary.json")
    for output in (other / "ticks.csv", tmp_path / "link.csv"):
        assert "run folder" in one_error(runner.invoke(app, ["record", "export", str(run), "-o", str(output)]))
    assert digests(run) == before and (other / "record.mcap").read_bytes() == (run / "record.mcap").read_bytes()


def test_a_damaged_record_named_as_its_own_output_is_kept(run, tmp_path):
    damaged = bytearray((run / "record.mcap").read_bytes())
    damaged[:4] = b"\0\0\0\0"  # no MCAP magic: only its name says what it is
    (tmp_path / "rec.mcap").write_bytes(damaged)
    line = one_error(runner.invoke(app, ["record", "export", str(tmp_path / "rec.mcap"),
                                         "-o", str(tmp_path / "rec.mcap")]))
    assert "is the record being read" in line
    assert (tmp_path / "rec.mcap").read_bytes() == damaged


def test_to_lerobot_leaves_a_partial_folder_it_did_not_make(run, tmp_path):
    stale = tmp_path / ".ds.partial"
    stale.mkdir()
    (stale / "notes.txt").write_text("someone's\n")
    result = runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert (stale / "notes.txt").read_text() == "someone's\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".ds.partial", "ds", "run"]  # its own staging is gone
    assert json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())["total_episodes"] == 6


def test_to_lerobot_into_a_file_or_the_current_folder_is_one_line(run, tmp_path, monkeypatch):
    (tmp_path / "afile").write_text("mine\n")
    result = runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(tmp_path / "afile")])
    assert "is a file" in one_error(result)
    monkeypatch.chdir(tmp_path)
    assert "not empty" in one_error(runner.invoke(app, ["record", "to-lerobot", str(run), "-o", "."]))
    assert sorted(os.listdir(tmp_path)) == ["afile", "run"] and (tmp_path / "afile").read_text() == "mine\n"


def test_to_lerobot_into_the_empty_current_folder_keeps_that_folder(run, tmp_path, monkeypatch):
    """The empty folder named by -o is written into, not replaced: a shell standing in it sees the dataset."""
    here = tmp_path / "here"
    here.mkdir()
    inode = here.stat().st_ino
    monkeypatch.chdir(here)
    result = runner.invoke(app, ["record", "to-lerobot", str(run), "-o", "."])
    assert result.exit_code == 0, result.output
    assert here.stat().st_ino == inode and sorted(os.listdir(".")) == ["data", "meta"]
    assert json.loads(Path("meta/info.json").read_text())["total_episodes"] == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["here", "run"]  # no staging left beside it


@pytest.mark.parametrize("name", ["rep[/].html", "rep[red]x.html", "rep\x1b[31m.html"])
def test_report_prints_the_path_it_was_given(run, tmp_path, name):
    out = tmp_path / name
    result = runner.invoke(app, ["report", str(run), "-o", str(out)])
    assert result.exit_code == 0, result.output
    shown = str(out).replace("\x1b", "\\x1b")  # the escape code written out, never sent to the terminal
    assert result.stdout == f"report: {shown}\n"
    assert "<html" in out.read_text()


def test_a_fifo_as_record_or_index_part_is_refused_not_waited_on(run, tmp_path):
    folder = tmp_path / "fifo"
    folder.mkdir()
    os.mkfifo(folder / "record.mcap")
    result = cli("record", "info", folder)
    assert result.returncode == 2 and "not a regular file" in result.stderr and "Traceback" not in result.stderr
    index = tmp_path / "index"
    part = index / _part(run).relative_to(run / "index")
    part.parent.mkdir(parents=True)
    part.write_bytes(_part(run).read_bytes())
    os.mkfifo(part.with_name("part-99999999.parquet"))
    result = cli("record", "query", index, "SELECT count(*) AS n FROM cycles", "--timeout", "5")
    assert result.returncode == 2 and "not a regular file" in result.stderr and result.stderr.count("\n") == 1


def test_a_baseline_without_motions_is_refused_and_kept(run, tmp_path):
    folder = tmp_path / "diagnosed"
    folder.mkdir()
    (folder / "record.mcap").write_bytes((run / "record.mcap").read_bytes())
    assert runner.invoke(app, ["diagnose", str(folder)]).exit_code == 0  # keeps its baseline beside the record
    baseline = json.loads((folder / "baseline.json").read_text())
    (folder / "baseline.json").write_text(json.dumps({**baseline, "motions": {}}))
    before = (folder / "baseline.json").read_text()
    assert "motions is empty" in one_error(runner.invoke(app, ["diagnose", str(folder)]))
    assert (folder / "baseline.json").read_text() == before


def _rewrite(source: Path, folder: Path, change) -> Path:
    """A copy of ``source``'s record, CRCs valid, with ``change(topic, data, i)`` applied to each message."""
    folder.mkdir()
    ids = {c.topic: c.id for c in CHANNELS}
    topics, seen = {v: k for k, v in ids.items()}, {}
    with open_record(source) as rec, open(folder / "record.mcap", "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD, enable_crcs=True)
        writer.start(profile=PROFILE, library="test")
        for name, values in rec.layout.metadata.items():
            writer.add_metadata(name, dict(values))
        for c in CHANNELS:
            schema = writer.register_schema(c.schema_name, c.schema_encoding, c.schema_text.encode())
            writer.register_channel(c.topic, c.message_encoding, schema)
        for m in rec.messages(list(ids)):
            topic = topics[m.channel_id]
            seen[topic] = i = seen.get(topic, -1) + 1
            writer.add_message(m.channel_id, m.log_time, change(topic, m.data, i), m.publish_time, m.sequence)
        writer.finish()
    return folder


def _measurement(edit):
    def change(topic, data, i):
        if topic != "/measurements" or i != 3:
            return data
        return edit(json.loads(data))
    return change


def _ragged(d):
    key = next(iter(d["measurements"]))
    d["measurements"][key] = d["measurements"][key][:-1]
    return json.dumps(d).encode()


@pytest.mark.parametrize("change, topic", [
    (_measurement(lambda d: b"not json"), "/measurements"),
    (_measurement(lambda d: json.dumps({k: v for k, v in d.items() if k != "t_ns"}).encode()), "/measurements"),
    (_measurement(_ragged), "/measurements"),
    (lambda topic, data, i: data[:len(data) // 2] if topic == "/ticks/decimated" and i == 10 else data,
     "/ticks/decimated"),
    (lambda topic, data, i: data[:len(data) // 2] if topic == "/chunks" and i == 2 else data, "/chunks"),
])
def test_a_malformed_message_is_skipped_with_one_warning(run, tmp_path, change, topic):
    folder = _rewrite(run, tmp_path / "bad", change)
    for command in (["record", "info"], ["record", "export", "-o", tmp_path / "t.csv"],
                    ["record", "to-lerobot", "-o", tmp_path / "ds"]):
        result = runner.invoke(app, [*command[:2], str(folder), *map(str, command[2:])])
        assert result.exception is None or isinstance(result.exception, SystemExit), result.output
        warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
        assert result.exit_code == 1 and len(warnings) == 1, result.output
        assert f"1 {topic} message(s) malformed, skipped" in warnings[0]
        assert "record recover" not in warnings[0]  # a recovered copy keeps the message as it is
    assert (tmp_path / "t.csv").is_file() and (tmp_path / "ds" / "meta" / "info.json").is_file()


def test_chunks_are_read_past_a_malformed_one(run, tmp_path):
    """Replay and the release evidence read every chunk; one malformed message is skipped, not the rest."""
    folder = _rewrite(run, tmp_path / "bad", lambda topic, data, i: data[:9] if topic == "/chunks" and i == 2 else data)
    whole = [c.t_received_ns for c in open_record(run).chunks()]
    read = [c.t_received_ns for c in open_record(folder).chunks()]
    assert len(whole) > 3 and read == whole[:2] + whole[3:]


def test_to_lerobot_on_a_full_disk_names_its_target_and_leaves_nothing(run, tmp_path, monkeypatch):
    """It left the empty target folder it had made, and its line named the hidden staging folder beside it."""
    import errno
    import os

    from cellguard.record import lerobot_export

    def full(path, table):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(lerobot_export, "_write_parquet", full)
    parent = tmp_path / "datasets"
    parent.mkdir()
    line = one_error(runner.invoke(app, ["record", "to-lerobot", str(run), "-o", str(parent / "x")]))
    assert line == f"error: -o {parent / 'x'}: cannot write (No space left on device)"
    assert list(parent.iterdir()) == []
