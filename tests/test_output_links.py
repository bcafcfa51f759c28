"""An output named through a link: the link is followed and never replaced by a file. Its final target is what is
checked and written (beside it, then renamed), so ``-o /dev/stdout > file`` fills the file, and a pipe or terminal
behind /dev/stdout is refused with one line."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from run_copies import recorded, run  # noqa: F401 (fixtures)

from cellguard.errors import OutputError
from cellguard.output import NAME_MAX, _temporary_name, write_output

needs_proc = pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd (Linux)")


def _export(run: Path, output: Path, stdout) -> subprocess.CompletedProcess:
    """``record export`` in a process of its own, its stdout given: what /dev/stdout is depends on it."""
    code = "from cellguard.cli import app; app()"
    return subprocess.run([sys.executable, "-c", code, "record", "export", str(run), "-o", str(output),
                           "--cycle", "0"], stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=120)


def test_a_link_to_a_file_rewrites_the_file_and_stays_a_link(tmp_path):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "real.csv").write_text("old")
    (tmp_path / "link.csv").symlink_to("data/real.csv")
    write_output(tmp_path / "link.csv", "new", "-o")
    assert os.readlink(tmp_path / "link.csv") == "data/real.csv"
    assert (tmp_path / "data" / "real.csv").read_text() == "new"
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == ["real.csv"]  # no temporary file left


def test_a_dangling_link_makes_its_target_where_it_points(tmp_path):
    (tmp_path / "data").mkdir()
    (tmp_path / "link.csv").symlink_to(tmp_path / "data" / "new.csv")
    write_output(tmp_path / "link.csv", "rows", "-o")
    assert (tmp_path / "link.csv").is_symlink() and (tmp_path / "data" / "new.csv").read_text() == "rows"


def test_a_dangling_link_into_a_missing_folder_is_refused_and_nothing_is_made(tmp_path):
    (tmp_path / "link.csv").symlink_to(tmp_path / "gone" / "new.csv")
    with pytest.raises(OutputError, match=r"link.csv: is a link to .*gone/new.csv, whose folder does not exist"):
        write_output(tmp_path / "link.csv", "rows", "-o")
    assert [p.name for p in tmp_path.iterdir()] == ["link.csv"] and (tmp_path / "link.csv").is_symlink()


@needs_proc
def test_a_link_to_an_open_file_descriptor_fills_that_file(tmp_path):
    """What ``-o /dev/stdout > file`` does, with a private link: the file is filled, the link kept."""
    with open(tmp_path / "redirected.csv", "w") as f:
        (tmp_path / "stdout").symlink_to(f"/proc/self/fd/{f.fileno()}")
        write_output(tmp_path / "stdout", "rows", "-o")
    assert (tmp_path / "stdout").is_symlink() and (tmp_path / "redirected.csv").read_text() == "rows"


@needs_proc
def test_a_link_to_a_deleted_open_file_is_refused(tmp_path):
    with open(tmp_path / "gone.csv", "w") as f:
        (tmp_path / "gone.csv").unlink()
        (tmp_path / "stdout").symlink_to(f"/proc/self/fd/{f.fileno()}")
        with pytest.raises(OutputError, match="which no file name reaches"):
            write_output(tmp_path / "stdout", "rows", "-o")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stdout"]


@needs_proc
def test_export_to_a_stdout_link_redirected_to_a_file_fills_the_file(run, tmp_path):
    link = tmp_path / "mystdout"
    link.symlink_to("/proc/self/fd/1")
    with open(tmp_path / "redirected.csv", "w") as out:
        result = _export(run, link, out)
    assert result.returncode == 0, result.stderr
    assert os.readlink(link) == "/proc/self/fd/1"  # it was replaced by a 276 kB file, and the redirect left empty
    rows = (tmp_path / "redirected.csv").read_text().splitlines()
    assert rows[0].startswith('"t_ns","cycle","joint"') and f"{len(rows) - 1} rows written" in result.stderr


@needs_proc
def test_export_to_a_stdout_link_on_a_pipe_is_one_line_and_writes_nothing(run, tmp_path):
    link = tmp_path / "mystdout"
    link.symlink_to("/proc/self/fd/1")
    result = _export(run, link, subprocess.PIPE)
    assert result.returncode == 2 and result.stdout == ""
    lines = result.stderr.splitlines()  # refused before the record is read, as any other output
    assert len(lines) == 1 and lines[0].startswith(f"error: -o {link}: is a FIFO, not a regular file; "), lines
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mystdout", "run"] and link.is_symlink()


def test_a_name_of_250_bytes_is_written(tmp_path):
    """The temporary name ``.NAME.PID.tmp`` went over 255 bytes: "File name too long" for a valid name."""
    target = tmp_path / ("a" * 246 + ".csv")
    write_output(target, "rows", "-o")
    assert target.read_text() == "rows" and [p.name for p in tmp_path.iterdir()] == [target.name]


@given(st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="/\0"), min_size=1, max_size=255)
       .filter(lambda s: len(os.fsencode(s)) <= NAME_MAX))
def test_a_temporary_name_fits_wherever_its_target_does(name):
    temporary = _temporary_name(name)
    assert len(os.fsencode(temporary)) <= NAME_MAX and temporary.startswith(".") and temporary != name
    assert "/" not in temporary


@pytest.mark.parametrize("magic, what", [(b"\x89MCAP0\r\n", "a record (MCAP)"),
                                         (b"SQLite format 3\x00", "an SQLite database (a store)")])
def test_a_link_to_a_record_or_a_store_is_never_written_through(tmp_path, magic, what):
    """A run folder's report.html linked to another run's record: the default report path followed the link and
    replaced that record with the page, exit 0."""
    other = tmp_path / "B" / "record.mcap"
    other.parent.mkdir()
    other.write_bytes(magic + b"the rest")
    link = tmp_path / "A" / "report.html"
    link.parent.mkdir()
    link.symlink_to("../B/record.mcap")
    with pytest.raises(OutputError, match=f"report {link}: is {re.escape(what)} \\(through a link to {other}\\); "
                                          "cellguard never overwrites a record or a store"):
        write_output(link, "<!doctype html>", "report")
    assert other.read_bytes() == magic + b"the rest" and link.is_symlink()
