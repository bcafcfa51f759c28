"""A process that ends with a recording still open (Ctrl-C in a caller with no stop handler: `cellguard bench`'s
record group) ends, and the record reads: at exit Python joined the recorder's writer process, which ignores SIGINT
and SIGTERM and waited for the end of its pipe, so the process hung until someone killed the writer."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from cellguard.record.reader import open_record

SCRIPT = """
import signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)  # as at a terminal: a shell's background job ignores it
from pathlib import Path
from cellguard.record.session import RunRecording
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}))
recording = RunRecording.start(Path(sys.argv[1]), run)
print("open", flush=True)
time.sleep(300)
"""


def test_ctrl_c_with_a_recording_open_ends_the_process_and_the_record_reads(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", SCRIPT, str(tmp_path / "run")], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    assert process.stdout.readline() == "open\n"
    process.send_signal(signal.SIGINT)
    try:
        _, err = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        children = subprocess.run(["pgrep", "-P", str(process.pid)], capture_output=True, text=True).stdout.split()
        for child in children:
            subprocess.run(["kill", "-KILL", child])
        process.communicate(timeout=30)
        pytest.fail("the process did not end within 60 s of SIGINT (the recorder's writer held it)")
    assert "KeyboardInterrupt" in err
    with open_record(tmp_path / "run") as record:
        assert record.health().finished and record.context["cell"] == "arm-pick-place"
