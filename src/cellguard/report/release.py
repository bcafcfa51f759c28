"""The release page: per stage the gates with their evidence and the difference against last_good.

In the incident report's style and with its helpers (``report.html``, ``report.plots``): one
self-contained HTML file, charts inline as SVG, nothing fetched.
"""

from __future__ import annotations

from pathlib import Path

from cellguard.output import write_output
from cellguard.record.outputs import PAGE, refuse_output
from cellguard.release import log
from cellguard.release.promotion import in_force_hashes
from cellguard.release.store import STAGES, STORE_FILE
from cellguard.report import plots
from cellguard.report.html import _CSS, _context, _e, _figure

_MARK = {"pass": "ok", "fail": "finding", "inconclusive": "finding"}


def render_release_page(store, release: str) -> str:
    bundle = store.bundle(release)
    entries = [e for e in log.entries(store) if bundle.id in (e.body.get("release"), e.body.get("from"),
                                                              e.body.get("to"))]
    in_force, error = in_force_hashes(store, bundle.cell)
    parts = [f"<h1>cellguard release {_e(bundle.id)}</h1>",
             f"<p class=muted>{_e(bundle.manifest['policy']['spec'])} on {_e(bundle.cell)}; "
             f"{_e(bundle.manifest.get('note', ''))}</p>", "<h2>Stages</h2>", _pointers(store, bundle)]
    if error:
        where = " for the stages named" if error.startswith("stage ") else ""  # a units file gone stops its stage
        parts.append(f"<p class=finding>the plan in force does not load{where}, so no pass counts there: "
                     f"{_e(error)}</p>")
    for stage in STAGES:
        evaluations = [e for e in entries if e.body.get("kind") == "gates" and e.body.get("stage") == stage
                       and e.body.get("release") == bundle.id]
        if evaluations:
            parts += [f"<h2>{_e(stage)}</h2>", _stage(evaluations[-1], in_force.get(stage))]
    parts += ["<h2>Log</h2>", _log(entries), "<h2>Manifest</h2>", _context(bundle.manifest)]
    return ("<!doctype html><html lang=en><head><meta charset=utf-8><title>cellguard release</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")


def write_release_page(store, release: str, out: Path) -> Path:
    """Write the page to ``out`` (beside it under a temporary name of this process, then renamed); refused first
    if ``out`` is the store read, any store, a record, in a run folder, or any file but a page (a page must never
    replace them: ``-o`` over the release's frozen policy left a release that could never run again)."""
    refuse_output(Path(out), None, inputs=[("release store", store.site / STORE_FILE)], kind=PAGE)
    return write_output(Path(out), render_release_page(store, release), "release page")


def _pointers(store, bundle) -> str:
    rows = ""
    for stage in STAGES:
        p = store.pointers(bundle.cell, stage)
        role = ", ".join(r for r, v in (("current", p.current), ("last_good", p.last_good)) if v == bundle.id)
        rows += (f"<tr><td>{stage}</td><td>{_e(p.current or '-')}</td><td>{_e(p.last_good or '-')}</td>"
                 f"<td>{_e(role or '-')}</td></tr>")
    return f"<table><tr><th>stage</th><th>current</th><th>last_good</th><th>this release</th></tr>{rows}</table>"


def _stage(entry, in_force: str | None) -> str:
    """The stage's latest gates of the release; a pass that counts for nothing under ``in_force`` (the stage's part
    of the plan in force now) is labelled as ``release status`` labels it (it showed as a plain pass)."""
    b = entry.body
    verdict, uncounted = b["verdict"], log.not_counted(b, in_force)
    shown = f"<b>{_e(verdict)}</b> ({_e(uncounted)}: counts for nothing)" if uncounted else f"<b>{_e(verdict)}</b>"
    head = (f"<div class={'finding' if uncounted else _MARK[verdict]}>{shown} (log entry {entry.seq}, {_e(b['at'])}); "
            f"evidence: records {_e(', '.join(b['evidence']) or 'none')}"
            + (f"; last_good's records {_e(', '.join(b.get('last_good_evidence', [])))}"
               if b.get("last_good_evidence") else "")
            + "".join(f"<br>not read as evidence: {_e(why)}" for why in b.get("refused", ())) + "</div>")
    rows = ""
    for g in b["gates"]:
        diff = ("-" if g["value"] is None or g["last_good"] is None
                else f"{g['value'] - g['last_good']:+.4g}")
        ev = "".join(f"<li>{_e(x)}</li>" for x in g["evidence"])
        rows += (f"<tr><td>{_e(g['metric'])}{' (hard)' if g['hard'] else ''}</td><td>{_e(g['status'])}</td>"
                 f"<td>{_fmt(g['value'])}</td><td>{_fmt(g['last_good'])}</td><td>{diff}</td>"
                 f"<td>{_e(g['condition'])}</td><td>{g['cycles']} / {g['min_cycles']}</td>"
                 f"<td>{_e(g['detail'])}<ul>{ev}</ul></td></tr>")
    table = ("<table><tr><th>gate</th><th>status</th><th>value</th><th>last_good</th><th>difference</th>"
             f"<th>condition</th><th>cycles / min</th><th>detail and evidence</th></tr>{rows}</table>")
    chart = _chart(b)
    return head + table + (_figure(f"gates-{b['stage']}", chart) if chart else "")


def _chart(body) -> str:
    """This release's figure against last_good's, per gate that has both (bars, each gate its own scale)."""
    pairs = [g for g in body["gates"] if g["value"] is not None and g["last_good"] is not None]
    if not pairs:
        return ""
    fig, axes = plots.plt.subplots(1, len(pairs), figsize=(2.4 * len(pairs), 2.4), squeeze=False)
    for ax, g in zip(axes[0], pairs):
        ax.bar([0, 1], [g["last_good"], g["value"]], color=[plots.BASE, plots.GOOD if g["status"] == "pass"
                                                            else plots.BAD])
        ax.set_xticks([0, 1], ["last_good", "this"], fontsize=7)
        ax.set_title(g["metric"], fontsize=7)
    fig.tight_layout()
    return plots._svg(fig)


def _log(entries) -> str:
    rows = "".join(f"<tr><td>{e.seq}</td><td>{_e(e.body['at'])}</td><td>{_e(e.body['kind'])}</td>"
                   f"<td>{_e(e.body.get('stage'))}</td><td>{_e(e.body.get('from') or '')} -&gt; "
                   f"{_e(e.body.get('to') or e.body.get('release'))}</td>"
                   f"<td>{_e(e.body.get('verdict') or e.body.get('reason') or '')}</td>"
                   f"<td><code>{e.hash[:16]}</code></td></tr>" for e in entries)
    return ("<table><tr><th>#</th><th>at (UTC)</th><th>kind</th><th>stage</th><th>move</th><th>verdict / reason</th>"
            f"<th>hash</th></tr>{rows}</table>")


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.4g}"


__all__ = ["render_release_page", "write_release_page"]
