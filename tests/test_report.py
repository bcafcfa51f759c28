"""The HTML report: self-contained, every chart present, and rendered by a real headless Chromium."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from cellguard.diagnose import diagnose
from cellguard.report import render_report
from cellguard.report import plots

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _rows():
    rng = np.random.default_rng(0)
    out = []
    for i in range(40):
        f = {"grasp_tcp_x_mm": 300 + 0.2 * rng.standard_normal() + (3.0 if i >= 30 else 0.0),
             "part_seen_x_mm": 300 + 0.2 * rng.standard_normal() + (3.0 if i >= 30 else 0.0),
             "part_seen_y_mm": 100 + 0.2 * rng.standard_normal(), "grasp_tcp_y_mm": 100 + 0.2 * rng.standard_normal(),
             "grasp_offset_x_mm": 0.1 * rng.standard_normal(), "grasp_offset_y_mm": 0.1 * rng.standard_normal(),
             "current_rms.elbow": 0.41 + 0.001 * rng.standard_normal(), "tracking_rms.elbow": 0.0133,
             "current_rms.wrist_flex": 0.93 + 0.001 * rng.standard_normal(), "tracking_rms.wrist_flex": 0.0196,
             "cycle_time_s": 4.444, "grasped": 1.0}
        out.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    return out


@pytest.fixture(scope="module")
def page() -> str:
    d = diagnose(_rows(), [{"t_ns": 140_000_000_000, "kind": "watchdog_stop", "reason": "policy silent",
                            "category": 2}], {"cell": "arm-pick-place", "fixture_datum": [0.3, 0.1, 0.0]})
    assert d.findings[0].cause == "fixture_shift"
    return render_report(d)


def test_report_is_self_contained_with_every_section(page):
    for plot in ("timeline", "overlay", "drift"):
        assert f'id="plot-{plot}"><svg' in page
    assert "fixture_shift" in page and "watchdog_stop" in page and "fixture_datum" in page
    for external in ('src="http', "src='http", 'href="http', "<link", "<script", "@import", "url(http"):
        assert external not in page  # nothing to fetch: it opens offline
    assert "no symmetry map" in page


def test_overlay_draws_ticks_when_the_record_has_them():
    t = np.linspace(0, 4, 400)
    trace = {"t": t, "current": np.c_[np.sin(t), np.cos(t)], "error": np.c_[t * 0, t * 1e-3]}
    svg = plots.overlay(["a", "b"], [(trace, "good"), ({**trace, "current": trace["current"] * 1.2}, "bad")])
    assert svg.startswith("<svg") and svg.count("<path") > 8


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed")
def test_headless_chromium_renders_the_plots(page, tmp_path):
    from PIL import Image

    html = tmp_path / "report.html"
    html.write_text(page)
    shot = tmp_path / "shot.png"
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    f"--user-data-dir={tmp_path / 'profile'}", "--hide-scrollbars", "--window-size=1280,2600",
                    f"--screenshot={shot}", html.as_uri()], check=True, capture_output=True, timeout=120)
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    inked = (np.abs(img - 255).sum(axis=2) > 60)
    rows = inked.mean(axis=1)
    assert inked.mean() > 0.02  # the page is not blank
    # plot regions: tall bands of ink across the page where the SVG charts are
    assert (rows > 0.05).sum() > 600
    for colour in ((0x2a, 0x9d, 0x8f), (0xe6, 0x39, 0x46)):  # success dots and the finding's line
        near = (np.abs(img - np.array(colour)).sum(axis=2) < 40).sum()
        assert near > 200, colour


def test_drift_charts_skip_channels_without_a_baseline_band():
    """Pooled per-joint channels alarm too but have no baseline band: the report still renders."""
    rows = _rows()
    rng = np.random.default_rng(1)
    for r in rows:  # a second current feature per joint, so the joint gets a pooled channel
        r["features"]["current_peak.elbow"] = 0.6 + 0.001 * rng.standard_normal()
    for r in rows[30:]:
        r["features"]["current_rms.elbow"] += 0.02
        r["features"]["current_peak.elbow"] += 0.02
    d = diagnose(rows, [], {"cell": "arm-pick-place"})
    pooled = [a.signal for a in d.drift.alarms if a.signal not in d.baseline.names]
    assert any("_pooled." in s for s in pooled)
    svg = plots.drift_charts(d)
    assert svg.startswith("<svg") and "current_rms.elbow" in svg
