"""Only completed, whole cycles become episodes; each cycle left out is named with why. A damaged chunk at a cycle's
start or end cut its episode short unnamed (or started it late, at timestamp 0), and a lost end marker dropped
the cycle unsaid; a cycle the operator's stop cut short was exported as an episode, braking included."""

from __future__ import annotations

import signal

import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from record_synth import rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.reader import open_record
from cellguard.record.schemas import TICKS
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()
STOP_AT_WRITE = 10_500  # [servo ticks] well into the third cycle (about 4.4 s each), the arm moving


@pytest.fixture(scope="module")
def stopped(tmp_path_factory):
    """Three cycles: the second fails its task (the tool slips), the operator stops the run mid-way through the third
    (SIGINT, as Ctrl-C)."""
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 4, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 2, "faults": [{"kind": "tool_slip", "at_cycle": 1}]})
    run, writes = Run(scenario), []
    write = run.cell.write

    def write_and_press(setpoint):
        writes.append(1)
        if len(writes) == STOP_AT_WRITE:
            signal.raise_signal(signal.SIGINT)
        return write(setpoint)

    run.cell.write = write_and_press
    out = tmp_path_factory.mktemp("run") / "run"
    run_scenario(scenario, out, run=run)
    with open_record(out) as rec:
        assert [c.success for c in rec.cycles()] == [True, False, False]
    assert run.stopped == "operator stop (SIGINT)"
    return out


def _export(folder, output):
    result = runner.invoke(app, ["record", "to-lerobot", str(folder), "-o", str(output)])
    episodes = pq.read_table(output / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    return result, [e["cellguard/cycle"] for e in episodes]


def test_a_cycle_the_operators_stop_cut_short_is_named_not_exported_and_a_failed_one_stays(stopped, tmp_path):
    result, episodes = _export(stopped, tmp_path / "ds")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == "skipped cycle 2: cut short by operator_stop", result.output
    assert lines[1].startswith("2 episodes,") and episodes == [0, 1]  # cycle 1 failed: data


def _damaged(out, marker: str, folder):
    """A copy of the record ``out`` in ``folder`` with the chunk holding the first cycle's end marker (``"end"``) or
    the second's begin marker (``"begin"``), both at the first cycle's end, damaged: 40 bytes flipped, its CRC fails
    and the reader skips it whole."""
    data = bytearray((out / "record.mcap").read_bytes())
    with open_record(out) as rec:
        at = rec.epoch_wall_ns + next(rec.cycles()).t_end_ns
    with open(out / "record.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    markers = next(i for i, c in summary.channels.items() if c.topic == "/cycles")
    holding = sorted((c for c in summary.chunk_indexes
                      if c.message_start_time <= at <= c.message_end_time and markers in c.message_index_offsets),
                     key=lambda c: c.chunk_start_offset)
    chunk = holding[0 if marker == "end" else -1]
    end = chunk.chunk_start_offset + chunk.chunk_length
    data[end - 400:end - 360] = bytes(b ^ 0x55 for b in data[end - 400:end - 360])
    folder.mkdir()
    (folder / "record.mcap").write_bytes(data)
    return folder


def _without_last_ticks(out, folder):
    """A copy of the record ``out`` in ``folder`` whose decimated tick batches of the first cycle's last 100 ms are
    unreadable (the reader skips each as malformed), its end marker whole."""
    with open_record(out) as rec:
        end = next(rec.cycles()).t_end_ns

    def edit(topic, data):
        lost = topic == "/ticks/decimated" and end - 100_000_000 < TICKS.decode(data)["t_ns"][-1] <= end
        return b"" if lost else data

    rewrite(out, folder, edit_bytes=edit)
    return folder


@pytest.mark.parametrize(("damage", "skipped", "kept"), [
    # the last 100 ms of cycle 0's ticks lost, its end marker whole: it was exported 7 frames short
    (_without_last_ticks, ["skipped cycle 0: ticks lost at its end"], [1]),
    # cycle 0's end marker lost (and its last 33 ms of ticks): it was left out unnamed
    (lambda out, folder: _damaged(out, "end", folder), ["skipped cycle 0: its end was lost"], [1]),
    # cycle 1's begin marker and first 100 ms lost: it was exported from 118 ms in, at timestamp 0
    (lambda out, folder: _damaged(out, "begin", folder), ["skipped cycle 1: ticks lost at its start"], [0]),
])
def test_a_cycle_whose_start_or_end_the_record_lost_is_named_not_exported(stopped, tmp_path, damage, skipped, kept):
    damaged = damage(stopped, tmp_path / "damaged")
    result, episodes = _export(damaged, tmp_path / "ds")
    assert result.exit_code == 1, result.output  # the record is damaged
    lines = result.output.splitlines()
    assert lines[:-2] == [*skipped, "skipped cycle 2: cut short by operator_stop"], result.output
    assert lines[-2].startswith(f"{len(kept)} episodes,") and episodes == kept, result.output
