"""Legitimate process changes the record declares, and how the diagnosis conditions on them.

The record's context lists the process changes declared so far (``context["process"]``: a new
product variant's payload, a restart after idle). A change the line declared is not a fault; its
kind's class (``robot/process``) says how it is conditioned on (``diagnosis``) and how a note names
it (``describe``), so a new kind needs no edit here. A kind this version does not know is not
conditioned on; a kind whose ``diagnosis`` is none of the ways below (misspelt, left out) is refused
when this module is imported, naming its class: it would not have been conditioned on, unseen.

- ``rebase`` (``payload``): every load-dependent feature (declared in ``feature_kinds``) moves with
  the new load. From the change on, those features are compared with a new centre, the median of the
  first ``REBASE`` cycles at the new load, keeping the acceptance scale; those cycles themselves
  are not watched. A fault that begins inside them is seen only once it grows further.
- ``settle`` (``warmup``): cold joints have more friction for the first cycles after idle, decaying.
  Each friction-dependent feature is not watched from the restart until it is back within
  ``SETTLED`` scales of its baseline (at most ``WARMUP_MAX`` cycles; a joint that never settles
  is watched again and alarms as it would).

An undeclared payload change is named by ``cause`` (``load_change``), never as a joint fault.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from cellguard import plugins
from cellguard.diagnose.baseline import Baseline
from cellguard.diagnose.cycles import Cycle
from cellguard.diagnose.feature_kinds import kind_of
from cellguard.robot.process import PROCESS_CHANGES
from cellguard.robot.process.base import ProcessChange

REBASE = 5  # [cycles] at a declared new load that set the new centre
SETTLED = 2.0  # [scales] a warm-up is over for a feature once it is back this close to its baseline
WARMUP_MAX = 40  # [cycles] longest warm-up allowed for


@dataclass(frozen=True)
class ProcessNote:
    """What the diagnosis did with one declared process change."""

    kind: str
    cycle: int
    text: str

    def to_dict(self) -> dict:
        return {"kind": self.kind, "cycle": self.cycle, "text": self.text}


def declared(context: Mapping | None) -> list[dict]:
    """The declared process changes in a record's context, earliest first (malformed entries skipped)."""
    raw = (context or {}).get("process") or []
    out = [c for c in raw if isinstance(c, Mapping) and isinstance(c.get("kind"), str)
           and isinstance(c.get("at_cycle"), int)]
    return sorted(out, key=lambda c: c["at_cycle"])


def condition(baseline: Baseline, cycles: Sequence[Cycle], z: np.ndarray,
              changes: Sequence[Mapping]) -> tuple[np.ndarray, tuple[ProcessNote, ...]]:
    """Residuals ``z`` (Shape (cycles, features)) with the declared changes accounted for, and notes."""
    z = z.copy()
    index = np.array([c.index for c in cycles])
    notes = []
    for change in changes:
        kind = PROCESS_CHANGES.get(change["kind"])
        how = _HOW.get(kind.diagnosis) if kind is not None else None
        rows = np.flatnonzero(index >= int(change["at_cycle"]))
        if how is not None and len(rows):
            notes.append(ProcessNote(change["kind"], int(change["at_cycle"]),
                                     f"{kind.describe(change)} declared at cycle {change['at_cycle']}: "
                                     + how(baseline, z, index, rows)))
    return z, tuple(notes)


def _rebase(baseline: Baseline, z: np.ndarray, index: np.ndarray, rows: np.ndarray) -> str:
    cols = np.array([j for j, n in enumerate(baseline.names) if kind_of(n).load], dtype=int)
    window = rows[:REBASE]
    with np.errstate(all="ignore"):
        shift = np.nanmedian(z[np.ix_(window, cols)], axis=0) if len(cols) else np.zeros(0)
    shift = np.where(np.isnan(shift), 0.0, shift)
    z[np.ix_(rows, cols)] -= shift
    z[np.ix_(window, cols)] = np.nan
    return f"{len(cols)} load-dependent features re-baselined on cycles {index[window[0]]}-{index[window[-1]]}"


def _settle(baseline: Baseline, z: np.ndarray, index: np.ndarray, rows: np.ndarray) -> str:
    cols = [j for j, n in enumerate(baseline.names) if kind_of(n).friction]
    span = rows[:WARMUP_MAX]
    settled_by = index[span[0]]
    for j in cols:
        col = z[span, j]
        back = np.flatnonzero(np.abs(col) <= SETTLED)
        end = back[0] if len(back) else len(span)
        z[span[:end], j] = np.nan
        if end:
            settled_by = max(settled_by, index[span[min(end, len(span) - 1)]])
    return (f"warm-up recognised, friction-dependent features watched again once back within {SETTLED:g} scales "
            f"(all by cycle {settled_by})")


_HOW = {"rebase": _rebase, "settle": _settle}  # by a kind's ``diagnosis``: each conditions ``z`` and says how


def _refuse_unknown_ways(kinds: Iterable[type[ProcessChange]]) -> None:
    """PluginError naming the first of ``kinds`` whose ``diagnosis`` is none of ``_HOW``'s, and the ways there are."""
    for kind in kinds:
        if kind.diagnosis not in _HOW:
            raise plugins.refused(sys.modules[kind.__module__],
                                  f"process change kind {kind.__module__}.{kind.__name__}: diagnosis "
                                  f"{kind.diagnosis!r} is not one of {', '.join(map(repr, _HOW))}")


_refuse_unknown_ways(PROCESS_CHANGES.values())
