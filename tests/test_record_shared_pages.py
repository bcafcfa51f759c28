"""After the recorder's writer is forked, the loop's process copies the pages it shares with it before the
first tick (wall time): the servo path's writes then take no copy-on-write fault."""

from __future__ import annotations

import os
import resource

import numpy as np
import pytest

from cellguard.record.session import RunRecording
from cellguard.record.shared_pages import copy_shared_pages
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

PAGES = 1024


def _faults_writing(buf: np.ndarray) -> int:
    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
    buf += 1.0
    return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before


@pytest.mark.parametrize("copy", [False, True])
def test_after_a_fork_a_write_faults_unless_the_shared_pages_were_copied(copy):
    buf = np.ones(PAGES * os.sysconf("SC_PAGE_SIZE") // 8)  # present before the fork
    go, wait = os.pipe()
    child = os.fork()
    if child == 0:  # holds the pages until told to go
        os.read(go, 1)
        os._exit(0)
    try:
        copied = copy_shared_pages() if copy else None
        faults = _faults_writing(buf)
    finally:
        os.write(wait, b"x")
        os.waitpid(child, 0)
    if copy and copied is None:
        pytest.skip("this OS cannot copy shared pages ahead (Linux 5.14 and /proc/self/pagemap)")
    if copy:  # the odd fault left is the interpreter's own, not one per page
        assert copied >= PAGES and faults < PAGES // 100
    else:
        assert faults >= PAGES  # one copy-on-write fault per page: what the copy saves the servo thread


@pytest.mark.parametrize("realtime", [False, True])
def test_a_recording_copies_the_shared_pages_on_wall_time_only(tmp_path, realtime):
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}),
              realtime=realtime)
    recording = RunRecording.start(tmp_path, run)
    try:
        copied = recording.pages_copied
    finally:
        recording.close()
        run.close()
    assert copied is None if not realtime else copied is None or copied > PAGES
