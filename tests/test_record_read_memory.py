"""Reading a record streams: the pages of the file's mapping a read has copied out are unmapped again, so reading
a record end to end leaves little of it resident in the process (the README's figures for ``record info``)."""

from __future__ import annotations

import pytest
from cli_util import record_run

from cellguard.record.reader import open_record


def _rss_file_kb() -> int | None:
    """The process's resident file-backed pages [KB] (Linux), else None."""
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("RssFile:"))
    except (OSError, StopIteration):
        return None


def test_reading_a_record_end_to_end_leaves_little_of_its_file_mapped(tmp_path):
    """The kernel maps a fault's neighbours too (64 KB windows): unmapping only each chunk's own pages left those
    before it mapped, and a full read held most of the file (39 of 52 MB; 11 of 12 MB for the demo's record)."""
    folder = record_run(tmp_path)
    size_kb = (folder / "record.mcap").stat().st_size // 1024
    with open_record(folder) as rec:
        before = _rss_file_kb()
        if before is None:
            pytest.skip("no /proc/self/status RssFile on this OS")
        rec.health()  # every chunk read once
        grew = _rss_file_kb() - before
    assert size_kb > 1024 and grew < 0.25 * size_kb, (grew, size_kb)
