"""Paths a command writes to or reads from: only a regular file is ever replaced (a device, FIFO or socket is
refused, never turned into a regular file), and a path that cannot even be looked at (a name over 255 bytes)
is one error line naming it, exit 2, not a traceback."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest
from cli_util import one_error
from run_copies import recorded, run  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import OutputError, RecordError
from cellguard.output import atomic_file, write_output

runner = CliRunner()
LONG = "a" * 300  # one path component over NAME_MAX (255)


@pytest.fixture
def unix_socket(tmp_path):
    """A socket file (no root needed, unlike a device node)."""
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(path))
        yield path


def _left(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# -- 1: only a regular file is replaced ------------------------------------------------------------
def test_a_fifo_or_socket_is_refused_and_a_link_to_a_regular_file_rewrites_the_file(tmp_path, unix_socket):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for target, kind in ((fifo, "a FIFO"), (unix_socket, "a socket")):
        with pytest.raises(OutputError, match=f"is {kind}, not a regular file"):
            write_output(target, "data", "report")
    assert fifo.is_fifo() and unix_socket.is_socket()
    assert _left(tmp_path) == ["fifo", "sock"]  # no temporary file left beside them
    (tmp_path / "real.txt").write_text("old")
    (tmp_path / "link.txt").symlink_to(tmp_path / "real.txt")
    write_output(tmp_path / "link.txt", "new", "report")  # the link stays, its target is replaced
    assert (tmp_path / "link.txt").is_symlink() and (tmp_path / "real.txt").read_text() == "new"


def test_a_link_to_a_device_is_refused_and_kept(tmp_path):
    """The device itself is never at risk here: a rename replaces the link, not /dev/null."""
    link = tmp_path / "out.html"
    link.symlink_to("/dev/null")
    with pytest.raises(OutputError, match="is a character device, not a regular file"):
        write_output(link, "x" * 1000, "report")
    assert link.is_symlink() and os.readlink(link) == "/dev/null"


def test_a_fifo_made_while_the_data_is_written_is_kept(tmp_path):
    target = tmp_path / "out.csv"
    with pytest.raises(OutputError, match="is a FIFO"):
        with atomic_file(target, "-o") as f:
            f.write(b"rows")
            os.mkfifo(target)  # appears after the check at the start
    assert target.is_fifo() and _left(tmp_path) == ["out.csv"]


def test_report_onto_a_device_fifo_or_socket_is_one_line_and_writes_nothing(run, tmp_path, unix_socket):
    fifo = tmp_path / "fifo.html"
    os.mkfifo(fifo)
    device = tmp_path / "null.html"
    device.symlink_to("/dev/null")
    for out, kind in ((fifo, "a FIFO"), (device, "a character device"), (unix_socket, "a socket")):
        line = one_error(runner.invoke(app, ["report", str(run), "-o", str(out)]))
        assert f"-o {out}: is {kind}, not a regular file" in line
    assert fifo.is_fifo() and device.is_symlink() and unix_socket.is_socket()
    assert not (run / "report.html").exists()


def test_a_fifo_as_a_run_folders_baseline_is_refused_not_replaced(run):
    os.mkfifo(run / "baseline.json")  # a run's own baseline is written by its first diagnosis
    line = one_error(runner.invoke(app, ["report", str(run)]))
    assert "baseline.json: is a FIFO, not a regular file" in line
    assert (run / "baseline.json").is_fifo() and not (run / "report.html").exists()
    assert not (run / "fixes.json").exists()  # nothing written before the refusal (fixes.json was)


# -- 4: a path that cannot be looked at ---------------------------------------------------------------
def test_reading_functions_name_a_path_they_cannot_look_at(tmp_path):
    from cellguard.diagnose.from_record import run_folder
    from cellguard.record.reader import open_record, record_file

    path = tmp_path / LONG
    for read in (record_file, open_record, run_folder):
        with pytest.raises(RecordError, match=f"{LONG}: cannot be read \\(File name too long\\)"):
            read(path)


@pytest.mark.parametrize("args", [["record", "info", "PATH"], ["report", "PATH"], ["diagnose", "PATH"],
                                  ["diagnose", "RUN", "--acceptance", "PATH"],
                                  ["record", "export", "PATH", "-o", "OUT"], ["record", "info", "RUN/PATH"],
                                  ["record", "query", "PATH", "SELECT 1"]])
def test_a_name_over_255_bytes_is_one_line_naming_it(run, tmp_path, args):
    path = str(tmp_path / LONG)
    args = [a.replace("RUN/PATH", str(run / LONG)).replace("PATH", path).replace("RUN", str(run))
            .replace("OUT", str(tmp_path / "out.csv")) for a in args]
    before = _left(run)
    line = one_error(runner.invoke(app, args))
    assert LONG in line and "File name too long" in line
    assert _left(run) == before


def test_a_dangling_link_on_the_way_to_a_folder_is_named(tmp_path):
    """``--out`` through a link whose target is gone said "cannot create the folder (File exists)"."""
    from cellguard.output import make_folder

    (tmp_path / "out").symlink_to(tmp_path / "gone")
    for target in (tmp_path / "out", tmp_path / "out" / "run"):
        with pytest.raises(OutputError, match=r"out is a link to .*gone, which does not exist"):
            make_folder(target, "--out")
    assert _left(tmp_path) == ["out"]
