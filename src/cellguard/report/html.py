"""The incident report: findings first, then the evidence a technician checks, then context.

One HTML file with its charts inline as SVG: it opens offline, months later, on any machine.
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Callable, Mapping

from cellguard.diagnose.compare import last_good_and_faulted
from cellguard.diagnose.diagnosis import FROM_START, Diagnosis, no_tick_words, record_facts, unwatched_words
from cellguard.diagnose.run_end import CUT_SHORT
from cellguard.report import plots

FOLD_CHARS = 600  # a context entry longer than this is folded in the report (click to open)
Trace = Mapping  # {"t": (n,) s into the cycle, "current": (n, dof) A, "error": (n, dof) rad, "joints": names}

_CSS = """
body{font-family:system-ui,sans-serif;margin:24px auto;max-width:1180px;color:#1d3557;background:#fff}
h1{font-size:22px;margin-bottom:4px}h2{font-size:17px;border-bottom:1px solid #ccd;padding-bottom:3px;margin-top:28px}
table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #dde;padding:3px 8px;text-align:left;vertical-align:top}
.finding{border-left:5px solid #e63946;padding:6px 12px;margin:10px 0;background:#fdf1f2}
.ok{border-left:5px solid #2a9d8f;padding:6px 12px;background:#eef8f6}
.damaged{border-left:5px solid #e9a23b;padding:6px 12px;margin:10px 0;background:#fdf6ea}
pre{margin:4px 0;font-size:12px;white-space:pre-wrap}figure.plot{margin:8px 0}figure.plot svg{max-width:100%;height:auto}.muted{color:#667}
"""


def render_report(d: Diagnosis, trace: Callable[[int], Trace | None] | None = None,
                  damage: str | None = None) -> str:
    """The report of ``d``; ``trace(cycle)`` gives a cycle's ticks for the overlay, if recorded. ``damage``: what
    a full read found wrong with the record, said at the top (the page of a cut record read as whole)."""
    ctx = d.context
    parts = [f"<h1>cellguard incident report: {_e(ctx.get('cell', 'cell'))}</h1>",
             *([f"<div class=damaged id=record-damage>The record is not whole: {_e(damage)}. This page shows what "
                "could be read.</div>"] if damage else []),
             _run(ctx),
             f"<p class=muted>{len(d.cycles)} cycles, baseline of {d.baseline.n} "
             f"({_e(d.baseline.source)}); site {_e(ctx.get('site', '?'))}, cell id {_e(ctx.get('cell_id', '?'))}</p>",
             "<h2>Findings</h2>", _findings(d), "<h2>Timeline</h2>", _figure("timeline", plots.timeline(d)),
             "<h2>Last good versus faulted</h2>", _last_good(d, trace), _changes(d),
             "<h2>Drift</h2>", _figure("drift", plots.drift_charts(d)),
             "<h2>Mirrored asymmetry</h2>", _asymmetry(d), "<h2>Guard events</h2>", _events(d),
             "<h2>Context</h2>", _context(ctx)]
    return ("<!doctype html><html lang=en><head><meta charset=utf-8><title>cellguard report</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")


def _e(v: object) -> str:
    return html.escape(str(v))


def _run(ctx: Mapping) -> str:
    """The line that dates the run and names its record, so the page can be traced on its own."""
    facts = {k: "unknown" if v is None else v for k, v in record_facts(ctx).items()}
    return (f"<p id=run>Run started <b>{_e(facts['start_utc'])}</b> (UTC), record <code>{_e(facts['record_id'])}"
            f"</code>, embodiment profile version {_e(facts['profile_version'])}</p>")


def _figure(name: str, svg: str) -> str:
    return f'<figure class=plot id="plot-{name}">{svg}</figure>'


def _findings(d: Diagnosis) -> str:
    notes = "".join(f"<div class=ok>{_e(n.text)}</div>" for n in d.process)  # declared process changes
    if d.unwatched:
        notes += f"<div class=ok>{_e(unwatched_words(d.unwatched, d.cycles))}</div>"
    if d.no_tick_features:  # a shorter comparison is no healthier one
        notes += f"<div class=ok>{_e(no_tick_words(d.no_tick_features, d.cycles))}</div>"
    if d.slip_gone is not None:  # "no fault" against a baseline that held a slip says why
        notes += f"<div class=ok>{_e(d.slip_gone.words())}</div>"
    if d.cut_short:
        notes += f"<div class=ok>Cycle {_e(', '.join(map(str, d.cut_short)))} {_e(CUT_SHORT)}.</div>"
    if d.run_end is not None:  # named as the text names it; a stop of the cell's with no finding is no "all clear"
        stopped = d.run_end.needs_cause and not d.findings
        notes += (f"<div class={'finding' if stopped else 'ok'} id=run-end>The run ended: {_e(d.run_end.words())}"
                  f"{'. No cause found for this stop in the record.' if stopped else ''}</div>")
        if stopped:
            return notes
    if not d.findings:
        return notes + "<div class=ok>No drift, fault or asymmetry found against the baseline.</div>"
    out = [notes]
    for f in d.findings:
        joints = f" on {', '.join(f.joints)}" if f.joints else ""
        items = "".join(f"<li>{_e(x)}</li>" for x in f.evidence)
        out.append(f"<div class=finding><b>{_e(f.cause)}</b>{_e(joints)} from cycle {f.cycle} "
                   f"(confidence {f.confidence:.2f})<ul>{items}</ul></div>")
    return "".join(out)


def _last_good(d: Diagnosis, trace: Callable[[int], Trace | None] | None) -> str:
    """The last good cycle against the first faulted, and the latest; where the cell has motions, all three of the
    first faulted one's motion (a right turn beside a left one differs by the turn), named in the labels."""
    if d.first_faulted_cycle is None:
        return "<p>No faulted cycle.</p>"
    good, bad = d.last_good_cycle, d.first_faulted_cycle
    none_before = FROM_START if d.from_start else "no good cycle before it"
    head = (f"<p>First faulted cycle <b>{bad}</b> ({_e(none_before)}).</p>" if good is None else
            f"<p>Last good cycle <b>{good}</b>, first faulted cycle <b>{bad}</b>.</p>")
    motion, same = _motion_of(d, bad)
    if motion:
        kept = None if good is None else last_good_and_faulted(same, bad)[0]
        good = None if kept is None else kept.index
        head += (f"<p>Overlaid: cycles of the first faulted one's motion, {_e(motion)}; its last good cycle is "
                 f"{'none' if good is None else f'<b>{good}</b>'}.</p>")
    of = f", {motion}" if motion else ""
    labels = (f"no good cycle{of}" if good is None else f"cycle {good} (last good{of})",
              f"cycle {bad} (first faulted{of})")
    joints = sorted({k.split(".", 1)[1] for c in d.cycles[:1] for k in c.features if k.startswith("current_rms.")},
                    key=lambda j: [k for k in d.cycles[0].features].index(f"current_rms.{j}"))
    latest = same[-1].index
    wanted = [(good, labels[0]), (bad, labels[1])] + ([(latest, f"cycle {latest} (latest{of})")] if latest > bad
                                                      else [])
    traces = [(trace(c), label) for c, label in wanted if c is not None] if trace is not None else []
    traces = [(t, label) for t, label in traces if t is not None]
    if traces:
        return head + _figure("overlay", plots.overlay(traces[0][0].get("joints", joints), traces))
    by = {c.index: c.features for c in d.cycles}
    return head + "<p class=muted>No tick data in the record for these cycles: per-cycle features shown.</p>" + \
        _figure("overlay", plots.feature_bars(joints, by.get(good, {}), by.get(bad, {}), labels))


def _motion_of(d: Diagnosis, cycle: int) -> tuple[str, list]:
    """The motion of ``cycle`` and the cycles of that motion, in order, where the cell has several; "" and all the
    cycles where it has one."""
    groups = plots.by_motion(d)
    if len(groups) > 1:
        for label, cycles in groups.items():
            if any(c.index == cycle for c in cycles):
                return label, cycles
    return "", list(d.cycles)


def _changes(d: Diagnosis) -> str:
    if not d.changes:
        return ""
    rows = "".join(f"<tr><td>{_e(c.signal)}</td><td>{c.onset}</td><td>{c.alarm_cycle}</td><td>{_num(c.baseline)}</td>"
                   f"<td>{_num(c.last_good)}</td><td>{_num(c.first_faulted)}</td><td>{_num(c.at_alarm)}</td>"
                   f"<td>{_num(c.change, '+.4g')}</td><td>{_num(c.scales, '+.1f')}</td></tr>" for c in d.changes)
    return ("<p>What changed, in the order it began:</p><table><tr><th>feature</th><th>onset</th><th>alarm</th>"
            "<th>baseline</th><th>last good</th><th>first faulted</th><th>at alarm</th><th>change</th>"
            f"<th>scales</th></tr>{rows}</table>")


def _num(v: float, spec: str = ".4g") -> str:
    """A table's number; a dash where there is none (no good cycle before the fault: NaN, which read "nan")."""
    return f"{v:{spec}}" if math.isfinite(v) else "-"


def _asymmetry(d: Diagnosis) -> str:
    a = d.asymmetry
    if a is None:
        return "<p class=muted>This cell has no symmetry map: no mirrored comparison.</p>"
    if a.side:
        verdict = (f"<div class=finding>The <b>{_e(a.side)}</b> side differs from its mirror "
                   f"({_e(', '.join(a.what))}).</div>")
    elif a.significant:  # the motions differ and no joint or leg tells the side: never "agree"
        verdict = f"<div class=finding>Mirrored motions differ {_e(a.where)} ({_e(', '.join(a.what))}).</div>"
    else:
        verdict = "<div class=ok>Mirrored motions agree.</div>"
    return verdict + _figure("asymmetry", plots.asymmetry_chart(d))


def _events(d: Diagnosis) -> str:
    """The guard's events, timed from the record's start (a run on wall time counts its clock from the host's boot)."""
    if not d.safety_events:
        return "<p>None.</p>"
    start = d.context.get("start_ns")
    t0 = start * 1e-9 if isinstance(start, int) else 0.0
    rows = "".join(f"<tr><td>{e['t'] - t0:.3f}</td><td>{_e(e.get('cycle'))}</td><td>{_e(e.get('kind'))}</td>"
                   f"<td>{_e(e.get('joint', ''))}</td><td>{_reading(e.get('asked'))}</td>"
                   f"<td>{_reading(e.get('sent'))}</td><td>{_e(e.get('category', ''))}</td>"
                   f"<td>{_e(e.get('reason', ''))}</td></tr>" for e in d.safety_events[:200])
    more = f"<p class=muted>{len(d.safety_events) - 200} more not shown.</p>" if len(d.safety_events) > 200 else ""
    head = ("<tr><th>t [s] from start</th><th>cycle</th><th>kind</th><th>joint</th><th>asked</th><th>sent</th><th>stop cat.</th>"
            "<th>reason</th></tr>")
    return f"<table>{head}{rows}</table>{more}"


def _reading(v: object) -> str:
    """An event's asked or sent value (SI) to nine digits (a limit often moves it in the seventh); empty if none."""
    return "" if v is None else _e(f"{v:.9g}" if isinstance(v, float) else v)


def _context(ctx: Mapping) -> str:
    if not ctx:
        return "<p class=muted>The record holds no context.</p>"
    rows = "".join(f"<tr><th>{_e(k)}</th><td>{_context_value(v)}</td></tr>" for k, v in ctx.items())
    return f"<table>{rows}</table>"


def _context_value(v: object) -> str:
    """One context entry, on one line; a long one (the profile's whole document is kilobytes) folded, its keys as
    the summary, indented inside: the table stays readable and nothing is left out."""
    text = v if isinstance(v, str) else json.dumps(v, default=str)
    if len(text) <= FOLD_CHARS:
        return f"<code>{_e(text)}</code>"
    keys = f"{', '.join(map(str, v))}" if isinstance(v, Mapping) else f"{len(text):,} characters"
    full = text if isinstance(v, str) else json.dumps(v, indent=1, default=str)
    return f"<details><summary>{_e(keys)}</summary><pre>{_e(full)}</pre></details>"
