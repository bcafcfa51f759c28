"""`release status` names a plan in force that does not load once, with every cell it stops: a site's
release-plan.yaml is every cell's plan in force, and its one error was printed again for each cell."""

from __future__ import annotations

from release_helpers import cli

from cellguard.release import Store, create_bundle, promote

CELLS = ("arm-pick-place", "quadruped-turns")


def test_a_broken_site_plan_is_named_once_with_every_cell_it_stops(tmp_path):
    site = tmp_path / "site"
    store = Store(site)
    for cell in CELLS:
        bundle = create_bundle("scripted", None, cell, None)
        store.add_bundle(bundle)
        promote(store, bundle.id, cell, "sim")
    store.close()
    (site / "release-plan.yaml").write_text("stages: [unclosed\n")
    said = cli("status", "--site", str(site))
    assert said.exit_code == 0
    lines = [line for line in said.stdout.splitlines() if "does not load" in line]
    assert len(lines) == 1 and said.stdout.count("release-plan.yaml") == 1
    assert lines[0].startswith(f"{', '.join(CELLS)}: the plan in force does not load, so nothing is promoted or run "
                               f"there until it does: {site / 'release-plan.yaml'}: ")
