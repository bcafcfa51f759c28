"""Who waits for a folder another process holds (``record.folder_lock``): a run's start waits out a report's brief
write beside a record (``BRIEF_S``); a staging folder held by a live ``to-lerobot`` or ``recover`` is refused at once.
The second waited ``BRIEF_S`` too, once the wait was every hold's: each refusal came a second late."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record import folder_lock, lerobot_export, recovery
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario

TINY = {"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 1, "production_cycles": 0}
# holds a folder as a report writing beside a record does, and lets go 0.2 s after the process named has opened the
# folder (its hold is trying then): a start that did not wait is refused
BRIEF_HOLDER = """
import os, sys, time
from cellguard.record import folder_lock
folder, waiter = sys.argv[1], sys.argv[2]
fd = folder_lock.hold(folder, wait_s=0)
print("held", flush=True)
key = (os.stat(folder).st_dev, os.stat(folder).st_ino)

def opened():
    for name in os.listdir(f"/proc/{waiter}/fd"):
        try:
            st = os.stat(f"/proc/{waiter}/fd/{name}")
        except OSError:
            continue
        if (st.st_dev, st.st_ino) == key:
            return True
    return False

deadline = time.monotonic() + 120
while not opened():
    if time.monotonic() > deadline:
        sys.exit("the folder was never opened")
    time.sleep(0.01)
time.sleep(0.2)
folder_lock.release(fd)
"""


@pytest.mark.parametrize("module, name", [(recovery, ".recover-abc12345.partial"),
                                          (lerobot_export, ".ds.abcd1234.partial")], ids=["recover", "to-lerobot"])
def test_a_staging_folder_a_live_run_holds_is_refused_at_once(tmp_path, module, name):
    """Both commands look at the staging folders of their target first (``_clear_stale_staging``)."""
    target = tmp_path / "ds"
    staging = (target if module is recovery else tmp_path) / name
    staging.mkdir(parents=True)
    live = folder_lock.hold(staging, "-o", wait_s=0)  # its run still writes there
    try:
        started = time.monotonic()
        with pytest.raises(RecordError, match=f"is writing there \\({name}\\)"):
            module._clear_stale_staging(target)
        took = time.monotonic() - started
    finally:
        folder_lock.release(live)
    assert took < 0.5  # it took BRIEF_S (1 s) more
    assert staging.is_dir()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the holder sees the start's hold in /proc")
@pytest.mark.parametrize("how", ["cli", "run_scenario"])
def test_a_runs_start_waits_out_a_brief_hold(tmp_path, monkeypatch, how):
    """``cellguard run`` holds its --out itself; ``run_scenario`` given no lock (a release's runs, an excitation run,
    the benchmarks) through its recording."""
    monkeypatch.setattr(folder_lock, "BRIEF_S", 10.0)  # the holder lets go in time on a loaded machine too
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", BRIEF_HOLDER, str(out), str(os.getpid())],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        if how == "cli":
            scenario = tmp_path / "tiny.yaml"
            scenario.write_text(yaml.safe_dump(TINY))
            result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(out)])
            assert result.exit_code == 0, result.output
        else:
            run_scenario(parse_scenario(TINY), out)
    finally:
        if holder.poll() is None:
            holder.kill()
        _, err = holder.communicate()
    assert holder.returncode == 0, err  # it let go only once the start was holding on
    assert (out / "summary.json").is_file()
