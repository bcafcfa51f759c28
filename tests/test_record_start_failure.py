"""A recording that fails while it is set up leaves no record.mcap: an empty or header-only one blocked the folder
("already holds a record") and read as an empty or truncated run."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from cellguard.record.writer import RECORD_FILE, refuse_existing

# Runs a one-cycle arm scenario with the longest pre-trigger window under an address-space limit of the process's
# size plus ``margin`` rings: the 47 MB ring the Recorder makes, once, in memory shared with its writer, is what runs
# out (``test_overwrite_failed_start``: 1.5 rings are enough)
SCRIPT = """
import json, resource, sys, traceback
from pathlib import Path
from cellguard.runtime.loop import Run, run_scenario
from cellguard.record.writer import RecordConfig
from cellguard.scenario import load_scenario

scenario = load_scenario(Path(sys.argv[1]))
run = Run(scenario)
config = RecordConfig(pre_trigger_s=300.0)
ring = (300_000 + 4 * 100 + 20) * (8 + 4 + 4 * 6 * 6)
size = next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith("VmSize:"))
limit = size + int(float(sys.argv[3]) * ring)
resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))
try:
    run_scenario(scenario, Path(sys.argv[2]), run=run, record=config)
    print(json.dumps({"error": None}))
except Exception as exc:
    cause = exc.__context__ or exc
    print(json.dumps({"type": type(exc).__name__, "error": str(exc),
                      "where": [frame.f_code.co_qualname for frame, _ in traceback.walk_tb(cause.__traceback__)]}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
@pytest.mark.parametrize("margin, where", [(0.5, "Recorder.__init__")])
def test_running_out_of_memory_while_the_recording_starts_leaves_no_record(tmp_path, margin, where):
    scenario = tmp_path / "one.yaml"
    scenario.write_text("cell: arm-pick-place\nseed: 7\npolicy: scripted\nacceptance_cycles: 1\nproduction_cycles: 0\n")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-c", SCRIPT, str(scenario), str(out), str(margin)], capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.splitlines()[-1])
    assert where in result["where"], result  # the file was created before the memory ran out
    assert [path.name for path in out.iterdir()] == []  # no record, no reserve file
    refuse_existing(out)  # the folder takes the next run
    assert result["type"] == "RecordError"
    # the shared ring's mapping (OSError ENOMEM) or its zeros (MemoryError), by a few MB
    assert re.fullmatch(rf"{re.escape(str(out / RECORD_FILE))}: cannot start the record \((MemoryError: .+|OSError: "
                        rf"Cannot allocate memory)\); nothing was run", result["error"]), result
