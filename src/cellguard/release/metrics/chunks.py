"""What the policy's chunks did: the steps at their seams and how late they came."""

from __future__ import annotations

import numpy as np

from cellguard.release.metrics import Measure, Metric, cycles_in


def chunk_seam_jump_max(runs) -> Measure:
    """Largest step between the outgoing and incoming chunk at each switch [mrad], as received
    (``reductions.reduce_chunks``)."""
    stepped = [r for r in runs if r.chunks.worst_seam_t_ns is not None]
    worst = max(stepped, key=lambda r: r.chunks.worst_seam_mrad, default=None)
    ev = (f"largest seam {worst.chunks.worst_seam_mrad:.1f} mrad in {worst.label()} at "
          f"t={worst.chunks.worst_seam_t_ns * 1e-9:.3f} s",) if worst else ()
    seams = sum(r.chunks.seams for r in runs)
    if not seams:
        return Measure(None, cycles_in(runs))
    return Measure(worst.chunks.worst_seam_mrad if worst else 0.0, cycles_in(runs), ev)


def inference_latency_p99(runs) -> Measure:
    """Observation-to-chunk latency the loop applied, p99 over chunks [ms]."""
    have = [r for r in runs if len(r.chunks.latency_ms)]
    if not have:
        return Measure(None, 0)
    worst = max(have, key=lambda r: (r.chunks.latency_ms.max(), r.label()))  # a tie: the last label, as ever
    value = float(np.percentile(np.concatenate([r.chunks.latency_ms for r in have]), 99))
    return Measure(value, cycles_in(runs), (f"worst {worst.chunks.latency_ms.max():.3g} ms in {worst.label()}",))


METRICS = (
    Metric("chunk_seam_jump_max_mrad", "mrad", chunk_seam_jump_max),
    Metric("inference_latency_p99_ms", "ms", inference_latency_p99),
)
