"""A cycle whose frames the dataset cannot hold is left out, named with why: its camera readings missing (a damaged
record) were frames of NaN, and NaN, infinities or values beyond float32 made meta/stats.json invalid JSON (NaN),
which LeRobot normalises every frame with."""

from __future__ import annotations

import json
import re

import pyarrow.parquet as pq
import pytest
from record_synth import rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record.lerobot_export import _write_json
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "run"
    run_scenario(parse_scenario({"cell": "arm-pick-place", "seed": 4, "policy": "scripted", "acceptance_cycles": 2,
                                 "production_cycles": 1}), out)
    return out


def _refused(value):
    raise ValueError(value)


UNFIT = r"observation.environment_state is NaN, infinite or beyond float32 in (\d+) of its \1 frames"


@pytest.mark.parametrize(("reading", "code", "why"), [
    (None, 1, "no camera or fixture readings recorded in it"),  # the reader skips them as malformed: exit 1
    (float("nan"), 0, UNFIT),
    (1e39, 0, UNFIT),  # inf once cast to float32
])
def test_a_cycle_whose_readings_the_dataset_cannot_hold_is_skipped_with_why(recorded, tmp_path, reading, code, why):
    def edit(topic, d):
        if topic == "/measurements" and d.get("cycle") == 1:
            d["measurements"] = {k: [reading] * len(v) for k, v in d["measurements"].items()}
        return d

    rewrite(recorded, tmp_path / "bad", edit=edit)
    result = runner.invoke(app, ["record", "to-lerobot", str(tmp_path / "bad"), "-o", str(tmp_path / "ds")])
    assert result.exit_code == code and isinstance(result.exception, SystemExit | None), result.output
    skipped, written = result.output.splitlines()[:2]
    assert re.fullmatch(f"skipped cycle 1: {why}", skipped) and written.startswith("2 episodes,"), result.output
    stats = json.loads((tmp_path / "ds/meta/stats.json").read_text(), parse_constant=_refused)  # strict JSON
    assert stats["observation.environment_state"]["count"] == [stats["index"]["count"][0]]
    episodes = pq.read_table(tmp_path / "ds/meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["cellguard/cycle"] for e in episodes] == [0, 2]


def test_stats_that_are_not_finite_are_an_error_never_a_file(tmp_path):
    with pytest.raises(RecordError, match=r"^meta/stats.json: Out of range float values are not JSON compliant"):
        _write_json(tmp_path / "stats.json", {"action": {"mean": [float("nan")]}})
    assert not (tmp_path / "stats.json").exists()
