"""The site's audit log is read as it is written: its own file in the site folder. A log that is a symbolic link
was refused for writes but followed by reads (`fleet audit` showed the file it pointed to as this site's log, exit
0; a push counted its batches); a hard link, a second name elsewhere of the same file, was not seen (a push
appended this site's entries to another site's log). Each is one line naming it, exit 2, nothing written; a hard link
is read as it is (a backup by hard links makes one: nothing to refuse in reading the site's own entries)."""

from __future__ import annotations

import datetime as dt
import os
import shutil

import pytest
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.audit import AUDIT_FILE, append_audit, read_audit, scan_audit
from cellguard.fleet.export import export_batch
from cellguard.fleet.policy import DataPolicy
from cellguard.fleet.push import push
from cellguard.fleet.signature import Signature

TODAY = dt.datetime.now(dt.timezone.utc).date()
POLICY = DataPolicy("ta", "s1")


def sigs() -> list[Signature]:
    return [Signature("ta", "s1", TODAY.isoformat(), "friction", 0.8, "arm5", "arm-pick-place",
                      {"current_rms.elbow": 6.0}, 7, 1)]


@pytest.fixture
def other_log(tmp_path):
    """Another site's audit log, with one entry."""
    other = tmp_path / "other"
    append_audit(other, export_batch(sigs(), POLICY, TODAY, key=b"k"), "queued", "nowhere")
    return other / AUDIT_FILE


def linked(tmp_path, other_log, how: str):
    site = tmp_path / "site"
    site.mkdir()
    if how == "symbolic":
        (site / AUDIT_FILE).symlink_to(other_log)
    else:
        os.link(other_log, site / AUDIT_FILE)
    return site


def test_fleet_audit_of_a_symbolically_linked_log_is_one_line_naming_it(tmp_path, other_log):
    site = linked(tmp_path, other_log, "symbolic")
    error = one_error(CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)]))
    assert f"--site-dir {site}: {AUDIT_FILE} is a link to {other_log}" in error, error
    for read in (scan_audit, read_audit):
        with pytest.raises(ConfigError, match=f"{AUDIT_FILE} is a link"):
            read(site)


def test_a_hard_linked_log_reads_and_its_next_append_names_the_copy_to_make(tmp_path, other_log):
    """A backup by hard links (cp -al) gives the site's log a second name: `fleet audit` shows it, a push is refused
    naming the log by its full path in the copy it advises."""
    site = linked(tmp_path, other_log, "hard")
    shown = CliRunner().invoke(app, ["fleet", "audit", "--site-dir", str(site)])
    assert shown.exit_code == 0 and "queued" in shown.stdout, shown.output
    with pytest.raises(ConfigError, match=rf"cp '{site / AUDIT_FILE}' '{site / AUDIT_FILE}.own'"):
        push(sigs(), POLICY, site, None, today=TODAY)


@pytest.mark.parametrize("how", ["symbolic", "hard"])
def test_a_push_into_a_site_whose_log_is_linked_is_refused_and_writes_nothing(tmp_path, other_log, how):
    site = linked(tmp_path, other_log, how)
    before = other_log.read_text()
    with pytest.raises(ConfigError, match=rf"{AUDIT_FILE}( is a link|: a hard link)"):
        push(sigs(), POLICY, site, None, today=TODAY)
    assert other_log.read_text() == before and sorted(p.name for p in site.iterdir()) == [AUDIT_FILE]
    policy = tmp_path / "p.yaml"
    policy.write_text("tenant: ta\nsite: s1\nexport: signatures\n")
    result = CliRunner().invoke(app, ["fleet", "push", str(tmp_path / "no-runs"), "--policy", str(policy),
                                      "--site-dir", str(site)])
    error = one_error(result)
    assert (f"{AUDIT_FILE} is a link" in error or f"{AUDIT_FILE}: a hard link" in error) and other_log.read_text() == before


def test_the_append_itself_refuses_a_hard_link(tmp_path, other_log):
    """What the push's check does not see (a link made after it): the append refuses the file it opened."""
    site = linked(tmp_path, other_log, "hard")
    before = other_log.read_text()
    with pytest.raises(OutputError, match=rf"audit log {site / AUDIT_FILE}: a hard link \(2 names of one file,"):
        append_audit(site, export_batch(sigs(), POLICY, TODAY, key=b"k"), "queued", "nowhere")
    assert other_log.read_text() == before


def test_after_the_advised_copy_the_log_is_the_sites_own(tmp_path, other_log):
    """cp audit.jsonl audit.jsonl.own && mv audit.jsonl.own audit.jsonl: the entries kept, the other log untouched."""
    site = linked(tmp_path, other_log, "hard")
    shutil.copyfile(site / AUDIT_FILE, site / f"{AUDIT_FILE}.own")
    os.replace(site / f"{AUDIT_FILE}.own", site / AUDIT_FILE)
    push(sigs(), POLICY, site, None, today=TODAY)
    assert [e["status"] for e in read_audit(site)] == ["queued", "queued"] and len(read_audit(other_log.parent)) == 1
