"""The incident replay page: recorded versus simulated joint positions and currents of one cycle, and the
profile the simulation ran with beside the record's, and where it was read from (a note at the top when they
differ, or its payload could not be had).

Self-contained HTML in the incident report's style (same CSS, inline SVG charts).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellguard.calibrate.replay import ReplayResult
from cellguard.output import write_output
from cellguard.record.reader import open_record, record_file
from cellguard.report.html import _CSS, _e, _figure, _run
from cellguard.report.plots import BAD, BASE, _svg, overlay, plt


def render_replay(r: ReplayResult, record: Path) -> str:
    """The page of ``r``, replayed from ``record`` (a run folder or an .mcap file), which it names."""
    d = r.to_dict()
    m = d["mismatch"]
    title = f"cellguard incident replay: {_e(r.rc.cell)}, cycle {r.rc.cycle}"
    hinge = [r.rc.joints.index(name) for name in m["joints"]]
    rows = "".join(f"<tr><td>{_e(r.rc.joints[j])}</td><td>{a:.3f}</td><td>{b * 1e3:.3f}</td><td>{c * 1e3:.3f}</td></tr>"
                   for j, a, b, c in zip(hinge, m["current_nrmse"], m["position_rms"], m["setpoint_max_gap"]))
    parts = [f"<h1>{title}</h1>", _record(record),
             *([f"<div class=damaged id=profile-note>{_e(r.profile.note)}</div>"] if r.profile.note else []),
             f"<p class=muted>{d['ticks']} recorded ticks replayed from the recorded start state in the "
             f"{_e(r.profile.model(r.model))}; the chunks recorded in the cycle went through a fresh guard.</p>",
             _profile_table(d)]
    if r.vary is not None:
        v = r.vary
        parts += ["<h2>Hypothesis</h2>",
                  f"<div class=finding>{_e(v.parameter)} of {_e(v.joint)} x <b>{r.best:.3f}</b> reproduces the "
                  "recorded "
                  f"cycle best (searched {v.low:g}..{v.high:g}; mean current NRMSE {m['cost']:.4f})</div>",
                  _figure("search", _search_chart(r))]
    parts += ["<h2>Recorded versus simulated</h2>", _figure("overlay", _overlay(r, hinge)),
              "<h2>Mismatch per joint</h2>",
              "<table><tr><th>joint</th><th>current NRMSE</th><th>position RMS [mrad]</th>"
              f"<th>largest setpoint gap [mrad]</th></tr>{rows}</table>"]
    return ("<!doctype html><html lang=en><head><meta charset=utf-8><title>cellguard replay</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")


def _profile_table(d: dict) -> str:
    """The profile replayed with, whole sha256 and all, beside the record's, and where it was read from (a file,
    the record's own document, the cell's own): which model this page shows."""
    source = d["profile"] or ("the cell's own" if d["profile_sha256"] else None)
    rows = [("model", d["model"]), ("profile version", d["profile_version"]), ("profile sha256", d["profile_sha256"]),
            ("calibration", d["calibration"]), ("profile read from", source),
            ("the record's profile sha256", d["record_profile_sha256"])]
    body = "".join(f"<tr><th>{name}</th><td>{_e('none' if value is None else value)}</td></tr>"
                   for name, value in rows)
    return f"<table id=profile>{body}</table>"


def _record(record: Path) -> str:
    """The record replayed, by id, start and file: a page of a loose .mcap, or one copied away, is traced on its own
    (pages of records side by side are told apart)."""
    with open_record(record) as rec:
        ctx = {**rec.context, "record_id": rec.record_id, "start_utc": rec.start_utc}
    return _run(ctx) + f"<p id=record-file>Record file <code>{_e(record_file(record).absolute())}</code></p>"


def write_replay(r: ReplayResult, out: Path, record: Path) -> Path:
    """Write the page of ``r``, replayed from ``record``, to ``out`` (beside it, then renamed)."""
    write_output(Path(out), render_replay(r, record), "replay report")
    return Path(out)


def _overlay(r: ReplayResult, joints: list[int]) -> str:
    """Simulated over recorded positions and currents of the replayed cycle, per joint."""
    def trace(x) -> dict:
        return {"t": x.t, "q": x.q[:, joints], "current": x.current[:, joints]}

    traces = [(trace(r.simulated), "simulated"), (trace(r.rc.ticks), "recorded")]
    return overlay([r.rc.joints[j] for j in joints], traces, rows=(("q", "position [rad]"), ("current", "current [A]")))


def _search_chart(r: ReplayResult) -> str:
    tried = np.array(sorted(r.search))
    fig, ax = plt.subplots(figsize=(5, 2.6))
    ax.plot(tried[:, 0], tried[:, 1], "o-", color=BASE, ms=3)
    ax.axvline(r.best, color=BAD, lw=0.8)
    ax.set_xlabel(f"{r.vary.parameter} factor on {r.vary.joint}", fontsize=8)
    ax.set_ylabel("mean current NRMSE", fontsize=8)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    return _svg(fig)
