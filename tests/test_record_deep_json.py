"""JSON in a record nested past what its readers recurse through: a crafted message or context copy 3000 levels deep
made json.loads raise RecursionError, and a context 900 deep the printing of ``record info``. Such a value is a
malformed message, skipped and reported as damage, and the rest of the record reads."""

from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
from record_synth import record, rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.json_values import MAX_DEPTH, loads
from cellguard.record.reader import open_record

runner = CliRunner()


@pytest.fixture(scope="module")
def original(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("orig")
    record(out, 10, 200, events={500: "position_clamp"})
    return out


def _nested(depth: int) -> list:
    value: list = []
    for _ in range(depth - 1):
        value = [value]
    return value


@contextmanager
def _deep_stack():
    """Room for json.dumps to write the crafted value (the reader under test runs at the default limit)."""
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(20_000)
    try:
        yield
    finally:
        sys.setrecursionlimit(limit)


def _craft(original: Path, target: Path, topic: str | None, depth: int, copy_too: bool = False) -> Path:
    """``original`` with a value ``depth`` levels deep in each ``topic`` message (in the context's policy for
    /context); ``copy_too``: in the context's copy at the end of the file."""
    deep = _nested(depth)

    def edit(t: str, d: dict) -> dict:
        if t == topic == "/context":
            d["context"]["policy"]["deep"] = deep
        elif t == topic:
            d["deep"] = deep
        return d

    with open_record(original) as rec:
        context = rec.context
    with _deep_stack():
        metadata = {"cellguard.context": {"context": json.dumps({**context, "deep": deep})}} if copy_too else None
        rewrite(original, target, metadata=metadata, edit=edit)
    return target


def _warned(result, folder: Path, note: str) -> None:
    """Exit 1 without a traceback, the one warning line naming the record and what was skipped."""
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), result.output
    warnings = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 1 and warnings[0].startswith(f"warning: {folder}: damaged") and note in warnings[0], \
        result.stderr


@pytest.mark.parametrize(("topic", "depth", "note"), [
    ("/events", 3000, "1 /events message(s) malformed"),
    ("/cycles", 3000, "20 /cycles message(s) malformed"),
    ("/context", 3000, "1 /context message(s) malformed"),
    ("/context", 900, "1 /context message(s) malformed"),  # decodes; printing the context recursed
    ("/events", MAX_DEPTH + 1, "1 /events message(s) malformed"),
])
def test_a_deeply_nested_message_is_skipped_as_malformed(original, tmp_path, topic, depth, note):
    run = _craft(original, tmp_path / "run", topic, depth)
    _warned(runner.invoke(app, ["record", "info", str(run)]), run, note)
    with open_record(run) as rec:
        cycles, events = list(rec.cycles()), list(rec.events())
        assert rec.context["site"] == "test-site"  # the context's copy at the end of the file, where it is skipped
    assert len(cycles) == (0 if topic == "/cycles" else 10) and len(events) == (0 if topic == "/events" else 1)


def test_a_context_and_its_copy_nested_too_deeply_leave_no_context(original, tmp_path):
    run = _craft(original, tmp_path / "run", "/context", 3000, copy_too=True)
    _warned(runner.invoke(app, ["record", "info", str(run)]), run, "the context is lost (no readable copy)")
    result = runner.invoke(app, ["diagnose", str(run)])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    assert result.stderr.splitlines() == [f"error: {run / 'record.mcap'}: the context record is missing or damaged"]


def test_a_deeply_nested_context_copy_is_not_read(original, tmp_path):
    """The copy is read only where the context message is lost; it was parsed, and raised, at every open."""
    run = _craft(original, tmp_path / "run", None, 3000, copy_too=True)
    result = runner.invoke(app, ["record", "info", str(run)])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize("command", [["diagnose"], ["report", "-o", "{tmp}/report.html"]])
def test_diagnose_and_report_read_past_a_deeply_nested_event(original, tmp_path, command):
    run = _craft(original, tmp_path / "run", "/events", 3000)
    result = runner.invoke(app, [command[0], str(run), *(a.format(tmp=tmp_path) for a in command[1:])])
    _warned(result, run, "1 /events message(s) malformed")


def test_loads_takes_max_depth_levels_and_no_more():
    assert loads(json.dumps(_nested(MAX_DEPTH))) == _nested(MAX_DEPTH)
    assert loads(b'{"a": [1, {"b": null}]}') == {"a": [1, {"b": None}]}
    assert loads(json.dumps({"text": "[{" * 500})) == {"text": "[{" * 500}  # brackets in text nest nothing
    for depth in (MAX_DEPTH + 1, 3000, 10**6):
        with pytest.raises(ValueError, match=f"nested deeper than {MAX_DEPTH} levels"):
            loads("[" * depth + "]" * depth)
