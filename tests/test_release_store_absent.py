"""Every release command but `create` refuses a site with no store, and every one refuses a store that is a link to
nothing. rollback, promote and run made an empty store at a mistyped --site (rollback then said only "nothing to roll
back to"), and at a dangling link's target (a share not mounted): status and verify then read it as the site's."""

from __future__ import annotations

import pytest
from release_helpers import CELL, cli

from cellguard.release.store import STORE_FILE

COMMANDS = {"rollback": ("rollback", "--cell", CELL), "promote": ("promote", "0123", "--cell", CELL, "--to", "sim"),
            "run": ("run", "--cell", CELL, "--stage", "sim"), "status": ("status",), "verify": ("verify",),
            "report": ("report", "0123")}
CREATE = ("create", "--policy", "scripted", "--profile", CELL)


@pytest.mark.parametrize("command", COMMANDS)
def test_a_site_with_no_store_is_refused_and_nothing_made(tmp_path, command):
    site, page = tmp_path / "typo-site", tmp_path / "page.html"
    result = cli(*COMMANDS[command], "--site", str(site), *(("-o", str(page)) if command == "report" else ()))
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == f"error: --site {site}: no release store there ({STORE_FILE}); release create " \
                                    f"makes one"
    assert not site.exists() and not page.exists()


@pytest.mark.parametrize("command", [*COMMANDS, "create"])
def test_a_store_that_is_a_link_to_nothing_is_refused_by_every_command(tmp_path, command):
    site, share = tmp_path / "site", tmp_path / "share"
    site.mkdir()
    share.mkdir()  # the link's folder is there, the store in it is not (an unmounted share's mount point)
    (site / STORE_FILE).symlink_to(share / STORE_FILE)
    result = cli(*(CREATE if command == "create" else COMMANDS[command]), "--site", str(site))
    assert result.exit_code == 2, result.output
    said = " ".join(result.stderr.split())
    assert said == f"error: --site {site}: {STORE_FILE} is a link to {share / STORE_FILE}, which is not there (a " \
                   f"share not mounted?); nothing read or created"
    assert list(share.iterdir()) == [] and sorted(p.name for p in site.iterdir()) == [STORE_FILE]


def test_create_makes_the_store_a_new_site_needs(tmp_path):
    site = tmp_path / "new-site"
    assert cli(*CREATE, "--site", str(site)).exit_code == 0
    assert (site / STORE_FILE).is_file() and cli("status", "--site", str(site)).exit_code == 0


@pytest.mark.parametrize("command", [*COMMANDS, "create"])
def test_a_store_that_is_a_folder_is_named_so_by_every_command(tmp_path, command):
    """It read as 'no release store there ... release create makes one', and create failed there."""
    site = tmp_path / "site"
    (site / STORE_FILE).mkdir(parents=True)
    result = cli(*(CREATE if command == "create" else COMMANDS[command]), "--site", str(site))
    assert result.exit_code == 2, result.output
    assert " ".join(result.stderr.split()) == f"error: --site {site}: {STORE_FILE} is not a file (a folder?); " \
                                              f"nothing read or created"


@pytest.mark.parametrize("command", COMMANDS)
def test_a_store_cut_to_nothing_is_refused_and_left_as_it_is(tmp_path, command):
    """A store file cut to 0 bytes (a failed copy, a full disk) read as an empty store: verify said "log whole: 0
    entries, chain verified" (exit 0), status and verify wrote a fresh schema into it, and the next promotion began
    a new chain beside the old runs."""
    site = tmp_path / "site"
    assert cli(*CREATE, "--site", str(site)).exit_code == 0
    (site / STORE_FILE).write_bytes(b"")
    result = cli(*COMMANDS[command], "--site", str(site), *(("-o", str(tmp_path / "p.html")) if command == "report"
                                                              else ()))
    assert result.exit_code == 2, result.output
    assert " ".join(result.stderr.split()) == f"error: --site {site}: {STORE_FILE} holds no release log (0 bytes: " \
                                              f"cut short by a failed copy or a full disk?); nothing read or " \
                                              f"created: restore it from a backup"
    assert (site / STORE_FILE).stat().st_size == 0


def test_an_ambiguous_release_prefix_lists_the_releases_it_matches_only(tmp_path):
    """It listed every release on the site, those that do not start with it too."""
    from cellguard.release.store import Store

    site = tmp_path / "site"
    for note in range(17):  # 17 ids: two share a first hex digit
        assert cli(*CREATE, "--note", str(note), "--site", str(site)).exit_code == 0
    ids = sorted(Store(site).bundle_ids())
    first = next(i[0] for i in ids if sum(j.startswith(i[0]) for j in ids) > 1)
    matching = [i for i in ids if i.startswith(first)]
    result = cli("promote", first, "--cell", CELL, "--to", "sim", "--site", str(site))
    assert result.exit_code == 2
    said = " ".join(result.stderr.split())
    assert said == f"error: release {first!r}: ambiguous, {len(matching)} releases start with it: {', '.join(matching)}"


@pytest.mark.parametrize("table", ["bundles", "pointers", "runs", "log", "meta"])
def test_a_store_missing_a_table_is_refused_naming_it(tmp_path, table):
    """A dropped pointers table was made again empty: status read "no release promoted yet" (exit 0)."""
    import sqlite3

    site = tmp_path / "site"
    assert cli(*CREATE, "--site", str(site)).exit_code == 0
    with sqlite3.connect(site / STORE_FILE) as db:
        db.execute(f"DROP TABLE {table}")
    result = cli("status", "--site", str(site))
    assert result.exit_code == 2, result.output
    assert " ".join(result.stderr.split()) == f"error: --site {site}: {STORE_FILE} lacks its table(s) {table} " \
                                              f"(edited outside cellguard?); nothing read or created: restore it " \
                                              f"from a backup"
