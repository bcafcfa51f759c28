"""Something other than a regular file where the site's audit log should be (a FIFO, a folder, a socket) is refused
before a command writes anything. It was refused only at the first append: by then a push had queued its batch in the
outbox (and made the site key, where the key was there to make), and `fleet withdraw` had deleted the site's
signatures from the lake, a deletion the log then never said."""

from __future__ import annotations

import datetime as dt
import os
import shutil
import socket
import subprocess
import sys

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import CellguardError
from cellguard.fleet.audit import AUDIT_FILE
from cellguard.fleet.export import export_batch
from cellguard.fleet.landing import write_signatures
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature
from cellguard.fleet.site_key import KEY_FILE, site_key

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY = DataPolicy("ta", "s1")
SIGS = [Signature("ta", "s1", TODAY.isoformat(), "friction", 0.8, "arm5", "arm-pick-place", {"current_rms.elbow": 6.0})]
KINDS = {"fifo": ("a FIFO", os.mkfifo), "folder": ("a folder", os.mkdir),
         "socket": ("a socket", lambda p: socket.socket(socket.AF_UNIX).bind(str(p)))}
ARMED: list[str] = []  # a log's path to turn into a folder when the append (O_CREAT) opens it


def _folder_at_append(event: str, args: tuple) -> None:
    if event == "open" and ARMED and str(args[0]) == ARMED[0] and isinstance(args[2], int) and args[2] & os.O_CREAT:
        os.remove(ARMED.pop())
        os.mkdir(args[0])


sys.addaudithook(_folder_at_append)  # inert unless a test arms it


def _site(tmp_path, kind: str, keyed: bool):
    """A site folder (with its key if ``keyed``) whose audit log's place holds a ``kind``; (folder, what it holds)."""
    site = tmp_path / "s"
    site.mkdir()
    if keyed:
        site_key(site)
    KINDS[kind][1](site / AUDIT_FILE)
    return site, {p.name: (p.read_bytes() if p.is_file() else None) for p in site.iterdir()}


@pytest.mark.parametrize("keyed", [True, False], ids=["keyed", "new"])
@pytest.mark.parametrize("kind", list(KINDS))
def test_a_push_whose_log_is_not_a_file_writes_nothing(tmp_path, kind, keyed):
    site, before = _site(tmp_path, kind, keyed)
    with pytest.raises(CellguardError, match=f"^{site / AUDIT_FILE}: is {KINDS[kind][0]}, not a regular audit log"):
        push(SIGS, POLICY, site, None, today=TODAY)
    after = {p.name: (p.read_bytes() if p.is_file() else None) for p in site.iterdir()}
    assert after == before  # no outbox, no batch queued, no new key, the key kept as it was
    assert (KEY_FILE in after) == keyed


def _pooled_lake(tmp_path):
    lake = tmp_path / "lake"
    batch = export_batch(SIGS, POLICY, TODAY, key=b"k")
    write_signatures(lake, batch.signatures, batch.batch_id)
    return lake


def _in_lake(lake) -> int:
    return len(list(lake.rglob("signatures/*/*.parquet")))


def _withdraw(tmp_path, lake, site):
    (tmp_path / "p.yaml").write_text("tenant: ta\nsite: s1\n")
    return CliRunner().invoke(app, ["fleet", "withdraw", "--policy", str(tmp_path / "p.yaml"), "--lake", str(lake),
                                    "--site-dir", str(site)])


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_withdrawal_whose_log_is_not_a_file_deletes_nothing(tmp_path, kind):
    lake = _pooled_lake(tmp_path)
    site, _ = _site(tmp_path, kind, keyed=False)
    assert one_error(_withdraw(tmp_path, lake, site)) == \
        f"error: {site / AUDIT_FILE}: is {KINDS[kind][0]}, not a regular audit log file"
    assert _in_lake(lake) == 1 and not (site / KEY_FILE).exists()


def test_a_withdrawal_whose_log_fails_after_the_deletion_names_what_went(tmp_path):
    """A deletion cannot be undone: a log that passed the check and cannot be appended to after the deletion (here
    made a folder as the append opens it; a full disk) is named with what went."""
    lake = _pooled_lake(tmp_path)
    site = tmp_path / "s"
    site.mkdir()
    (site / AUDIT_FILE).write_text("")
    ARMED.append(str(site / AUDIT_FILE))
    error = one_error(_withdraw(tmp_path, lake, site))
    assert not ARMED and _in_lake(lake) == 0, error
    assert error.endswith("is a folder, not a regular audit log file; deleted already: 1 signature(s) from the lake "
                          "of site s1"), error


def test_similar_checks_the_log_before_it_reads_the_runs(tmp_path):
    """`fleet similar RUN` logs its probes before it sends them: a log it cannot append to is named before the runs
    are diagnosed (here a folder with no record, which the diagnosis would have named first)."""
    site, _ = _site(tmp_path, "fifo", keyed=False)
    (tmp_path / "runs").mkdir()
    (tmp_path / "p.yaml").write_text("tenant: ta\nsite: s1\nexport: signatures\n")
    error = one_error(CliRunner().invoke(app, ["fleet", "similar", str(tmp_path / "runs"), "--policy",
                                               str(tmp_path / "p.yaml"), "--site-dir", str(site), "--store",
                                               "host=127.0.0.1 port=1 dbname=x user=x password=x"]))
    assert error == f"error: {site / AUDIT_FILE}: is a FIFO, not a regular audit log file"


def test_a_withdrawal_into_a_site_folder_it_cannot_write_deletes_nothing(tmp_path):
    """No log yet and a site folder it cannot write: the log could never say what went, yet the lake was emptied
    first ("cannot append (Permission denied); deleted already: 1 signature(s)")."""
    lake = _pooled_lake(tmp_path)
    site = tmp_path / "s"
    site.mkdir()
    site.chmod(0o555)
    (tmp_path / "p.yaml").write_text("tenant: ta\nsite: s1\n")
    command = [sys.executable, "-c", "from cellguard.entry import main; main()", "fleet", "withdraw", "--policy",
               str(tmp_path / "p.yaml"), "--lake", str(lake), "--site-dir", str(site)]
    if os.geteuid() == 0:  # root writes anywhere: run it without the capabilities that let it
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: no folder it cannot write")
        command = ["setpriv", "--bounding-set", "-dac_override,-dac_read_search", *command]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stderr) == (
        2, f"error: audit log {site / AUDIT_FILE}: cannot create it (its folder is not writable)\n")
    assert _in_lake(lake) == 1
