"""The site's audit log is checked as the file opened, not as the path before it is opened. Read, the log's path was
checked for a link and then opened following links: a link swapped in between showed another site's log as this
one's (`fleet audit`, exit 0; a push counted its batches). Appended to, a FIFO in the log's place was opened to wait
for a reader: the push hung for good.

The swap happens at the open itself: an audit hook (``sys.addaudithook``) sees each ``open`` just before the
system call, after every check the code made on the path, and replaces the site's log there with a link."""

from __future__ import annotations

import datetime as dt
import os
import subprocess
import sys

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.audit import AUDIT_FILE, AuditError, append_audit, read_audit, scan_audit
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import site_key

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY = DataPolicy("ta", "s1")
BATCH = export_batch([Signature("ta", "s1", TODAY.isoformat(), "friction")], POLICY, TODAY, key=b"k")
SWAPS: list[tuple[str, str]] = []  # (a log's path, the file to link there when it is next opened)


def _swap_at_open(event: str, args: tuple) -> None:
    if event == "open" and SWAPS and str(args[0]) == SWAPS[0][0]:
        path, target = SWAPS.pop()
        os.remove(path)
        os.symlink(target, path)


sys.addaudithook(_swap_at_open)  # inert unless a test queues a swap


@pytest.fixture
def sites(tmp_path):
    """(this site, with one entry of its own; another site's log, with three)."""
    other, site = tmp_path / "other", tmp_path / "site"
    for _ in range(3):
        append_audit(other, BATCH, "queued", "nowhere")
    append_audit(site, BATCH, "sent", "nowhere")
    yield site, other / AUDIT_FILE
    SWAPS.clear()


@pytest.mark.parametrize("read", [scan_audit, read_audit])
def test_a_link_swapped_in_when_the_log_is_opened_is_refused_not_read(sites, read):
    site, other_log = sites
    SWAPS.append((str(site / AUDIT_FILE), str(other_log)))
    with pytest.raises(ConfigError, match=f"^--site-dir {site}: {AUDIT_FILE} is a link to {other_log}; the site's"):
        read(site)
    assert not SWAPS  # the swap happened, at the open


def test_fleet_audit_of_a_log_swapped_for_a_link_at_its_open_is_one_line_exit_2(sites):
    site, other_log = sites
    SWAPS.append((str(site / AUDIT_FILE), str(other_log)))
    error = one_error(CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)]))
    assert f"{AUDIT_FILE} is a link to {other_log}" in error and not SWAPS, error


def test_the_sites_own_log_and_a_hard_linked_one_still_read(sites, tmp_path):
    site, other_log = sites
    assert [e["status"] for e in read_audit(site)] == ["sent"]
    os.link(site / AUDIT_FILE, tmp_path / "backup.jsonl")  # a backup by hard links: read as it is
    assert [e["status"] for e in read_audit(site)] == ["sent"]
    (tmp_path / "new").mkdir()
    assert scan_audit(tmp_path / "new") == ([], [])  # no log yet
    with pytest.raises(OutputError, match=r": a hard link \(2 names of one file"):
        append_audit(site, BATCH, "queued", "nowhere")


def test_a_push_into_a_site_whose_log_is_a_fifo_is_one_line_exit_2_not_a_hang(tmp_path):
    site = tmp_path / "site"
    site_key(site)  # a site that pushed before: no read of its log comes first
    os.mkfifo(site / AUDIT_FILE)
    (tmp_path / "runs").mkdir()
    (tmp_path / "p.yaml").write_text("tenant: ta\nsite: s1\nexport: nothing\n")
    done = subprocess.run([sys.executable, "-c", "from cellguard.cli import app; app()", "fleet", "push",
                           str(tmp_path / "runs"), "--policy", str(tmp_path / "p.yaml"), "--site-dir", str(site)],
                          capture_output=True, text=True, timeout=120)  # hung, it is killed here and the test fails
    assert done.returncode == 2 and done.stdout == "", (done.returncode, done.stdout, done.stderr)
    assert done.stderr == f"error: {site / AUDIT_FILE}: is a FIFO, not a regular audit log file\n", done.stderr
    reader = os.open(site / AUDIT_FILE, os.O_RDONLY | os.O_NONBLOCK)  # with a reader it opens: its fstat refuses it
    try:
        with pytest.raises(OutputError, match=f"^{site / AUDIT_FILE}: is a FIFO, not a regular audit log file$"):
            append_audit(site, BATCH, "queued", "nowhere")
        assert os.read(reader, 1 << 16) == b""  # nothing written into it
    finally:
        os.close(reader)


def test_a_socket_in_the_logs_place_is_named_as_one(tmp_path):
    """It read "cannot read the audit log file (No such device or address)"."""
    import socket

    site = tmp_path / "site"
    site.mkdir()
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(site / AUDIT_FILE))
        with pytest.raises(AuditError, match=f"^{site / AUDIT_FILE}: is a socket, not a regular audit log file$"):
            scan_audit(site)
