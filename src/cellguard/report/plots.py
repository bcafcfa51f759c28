"""The report's charts, drawn with matplotlib (Agg) and returned as inline SVG text.

SVG keeps the page self-contained (no script, no network) and sharp when printed.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cellguard.diagnose.cycles import Cycle  # noqa: E402
from cellguard.diagnose.diagnosis import Diagnosis  # noqa: E402

GOOD, BAD, ALARM, BASE = "#2a9d8f", "#e63946", "#f4a261", "#8d99ae"
MOTION_COLOURS = ("#264653", "#e76f51", "#6a4c93", "#2a9d8f")  # the first: a one-motion cell's values, as before


def _svg(fig) -> str:
    """The figure as SVG text that is the same each time it is drawn: no date (the report's date is the run's,
    not when the page was written) and element ids hashed with a fixed salt instead of a random one."""
    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": "cellguard-report"}):
        fig.savefig(buf, format="svg", bbox_inches="tight", metadata={"Date": None})
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]


def timeline(d: Diagnosis) -> str:
    """Cycles in order: success, acceptance shading, drift alarms, findings and safety events."""
    fig, ax = plt.subplots(figsize=(11, 2.6))
    idx = np.array([c.index for c in d.cycles])
    ok = np.array([c.success for c in d.cycles])
    acc = [c.index for c in d.cycles if c.phase == "acceptance"]
    if acc:
        ax.axvspan(min(acc) - 0.5, max(acc) + 0.5, color=BASE, alpha=0.15, label="acceptance (baseline)")
    ax.scatter(idx[ok], np.ones(ok.sum()), color=GOOD, s=18, label="success")
    ax.scatter(idx[~ok], np.ones((~ok).sum()), color=BAD, s=18, marker="x", label="failed")
    for a in d.drift.alarms:
        ax.vlines(a.cycle, 1.3, 1.9, color=ALARM, lw=1)
    if d.drift.alarms:
        ax.vlines([], 0, 0, color=ALARM, label="drift alarm")
    for i, f in enumerate(d.findings):
        ax.axvline(f.cycle, color=BAD, lw=2, alpha=0.6)
        ax.text(f.cycle, 2.05 + 0.2 * (i % 2), f" {f.cause}", color=BAD, fontsize=9, va="bottom")
    ev = [e["cycle"] for e in d.safety_events if e.get("cycle") is not None]
    if ev:
        ax.scatter(ev, np.full(len(ev), 0.6), color="black", marker="v", s=30, label="guard event")
    ax.set_ylim(0.3, 2.7)
    ax.set_yticks([])
    ax.set_xlabel("cycle")
    ax.legend(loc="upper left", fontsize=8, ncol=5, bbox_to_anchor=(0, -0.35))
    return _svg(fig)


def by_motion(d: Diagnosis) -> dict[str, list[Cycle]]:
    """The cycles per motion the baseline keeps statistics for (a cell's left and right turns), in order; all in one
    group where it keeps one set (a cell of one motion)."""
    if len(d.baseline.motions) == 1:
        return {next(iter(d.baseline.motions)): list(d.cycles)}
    return {label: [c for c in d.cycles if (c.label or "") == label] for label in d.baseline.motions}


def drift_charts(d: Diagnosis, limit: int = 6) -> str:
    """The drift charts of ``d`` as SVG (``drift_figure``)."""
    return _svg(drift_figure(d, limit))


def drift_figure(d: Diagnosis, limit: int = 6):
    """Per alarmed feature: its value per cycle against the baseline band, and its CUSUM. A cell of several motions
    gets one band per motion, each motion's values in its band's colour: the diagnosis reads each cycle against its
    own motion's statistics, and their average is a band no turn lies in."""
    # features with a baseline band; the pooled per-joint channels and the multivariate statistic have none
    names = list(dict.fromkeys(a.signal for a in d.drift.alarms if a.signal in d.baseline.names))[:limit]
    rows = len(names) + 1
    fig, axes = plt.subplots(rows, 2, figsize=(11, 2.0 * rows), squeeze=False)
    watched = np.array(d.drift.cycles)
    groups = by_motion(d)
    for r, name in enumerate(names):
        ax, cx = axes[r]
        j = d.baseline.names.index(name)
        for k, (label, cycles) in enumerate(groups.items()):
            stats, colour = d.baseline.motions[label], MOTION_COLOURS[k % len(MOTION_COLOURS)]
            med, sc = stats.median[j], stats.scale[j]
            ax.axhspan(med - 3 * sc, med + 3 * sc, color=BASE if len(groups) == 1 else colour, alpha=0.25)
            ax.plot([c.index for c in cycles], [c.features.get(name, np.nan) for c in cycles], ".-", color=colour,
                    ms=3, lw=0.8, **({"label": f"{label}: value and band"} if len(groups) > 1 else {}))
        ax.set_title(name, fontsize=9, loc="left")
        up, lo = d.drift.series(name)
        cx.plot(watched, up, color=BAD, lw=1, label="CUSUM up")
        cx.plot(watched, lo, color="#457b9d", lw=1, label="CUSUM down")
        cx.axhline(d.drift.threshold, color="black", ls="--", lw=0.8, label="threshold")
        cx.set_title(f"{name}: CUSUM", fontsize=9, loc="left")
    ax, cx = axes[-1]
    ax.axis("off")
    ax.text(0, 0.5, f"CUSUM k = {d.drift.k:g}, h = {d.drift.threshold:.2f}\n"
                    f"{len(d.drift.names)} features watched", fontsize=9, va="center")
    cx.plot(watched, d.drift.mewma, color="#6a4c93", lw=1)
    cx.axhline(d.drift.mewma_threshold, color="black", ls="--", lw=0.8)
    cx.set_title("multivariate EWMA (T²)", fontsize=9, loc="left")
    cx.set_xlabel("cycle")
    if names:
        axes[0][1].legend(fontsize=7)
        if len(groups) > 1:
            axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    return fig


OVERLAY_ROWS = (("current", "current [A]"), ("error", "tracking error [rad or m]"))


def overlay(joints: Sequence[str], traces: Sequence[tuple[Mapping, str]],
            rows: Sequence[tuple[str, str]] = OVERLAY_ROWS) -> str:
    """Traces per joint against time in cycle, one row per (key, axis label) of ``rows``: by default
    current and tracking error of the last good versus faulted cycles.

    ``traces`` are (trace, label) in order: last good, first faulted, then any later cycle; a
    trace maps ``t`` (n,) and each row's key to (n, joints).
    """
    n = len(joints)
    colours = (GOOD, BAD, "#6a4c93")
    fig, axes = plt.subplots(len(rows), n, figsize=(max(11, 2.2 * n), 2.2 * len(rows)), squeeze=False, sharex=True)
    for j, name in enumerate(joints):
        for (trace, label), color in zip(traces, colours):
            for row, (key, _) in enumerate(rows):
                axes[row][j].plot(trace["t"], trace[key][:, j], color=color, lw=0.7, label=label)
        axes[0][j].set_title(name, fontsize=9)
        axes[-1][j].set_xlabel("s into cycle", fontsize=8)
    for row, (_, unit) in enumerate(rows):
        axes[row][0].set_ylabel(unit, fontsize=8)
    axes[0][0].legend(fontsize=7)
    for ax in axes.flat:
        ax.tick_params(labelsize=7)
    fig.tight_layout()
    return _svg(fig)


def feature_bars(joints: Sequence[str], good: Mapping[str, float], bad: Mapping[str, float],
                 labels: tuple[str, str]) -> str:
    """Without ticks: per-joint current and tracking features of the two cycles side by side."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 3))
    x = np.arange(len(joints))
    for ax, kind, unit in ((axes[0], "current_rms", "A"), (axes[1], "tracking_rms", "rad")):
        for k, (vals, color, label) in enumerate(((good, GOOD, labels[0]), (bad, BAD, labels[1]))):
            ax.bar(x + (k - 0.5) * 0.4, [vals.get(f"{kind}.{j}", np.nan) for j in joints], 0.4, color=color,
                   label=label)
        ax.set_xticks(x, joints, rotation=30, fontsize=8)
        ax.set_title(f"{kind} [{unit}]", fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return _svg(fig)


def asymmetry_chart(d: Diagnosis) -> str:
    """Mirrored differences, left member minus its mirror, as a percentage of their mean."""
    diffs = sorted(d.asymmetry.differences, key=lambda x: -abs(x.relative))[:16] if d.asymmetry else []
    fig, ax = plt.subplots(figsize=(11, 0.35 * max(len(diffs), 4) + 1))
    if diffs:
        y = np.arange(len(diffs))
        ax.barh(y, [100 * x.relative for x in diffs], color=[BAD if x.significant else BASE for x in diffs])
        ax.set_yticks(y, [x.left for x in diffs], fontsize=7)
        ax.invert_yaxis()
        ax.axvline(0, color="black", lw=0.8)
        for v in (-5, 5):
            ax.axvline(v, color="black", ls=":", lw=0.8)
    ax.set_xlabel("left minus mirrored right [% of mean]; red = asymmetric")
    fig.tight_layout()
    return _svg(fig)
