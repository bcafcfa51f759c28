"""Gate metrics, each computed from a stage's run records; one registry, filled from this package's modules.

A metric returns ``Measure(value, cycles, evidence)``: ``cycles`` is how much data it saw (a
gate with fewer than ``min_cycles`` is inconclusive), ``evidence`` names the records and cycles
that made the value what it is (a failed cycle, a stop, the worst seam). ``value`` is None when
the runs hold nothing to measure (no shadow data, no acceptance baseline). A metric that only some cells
or only shadow runs can report says so (``needs``, ``shadow``): a gate on it elsewhere could only end
inconclusive, so a plan's stage holding one is refused before it runs.

A new metric is one new module here: it defines ``METRICS``, a tuple of ``Metric``, and ``discover`` finds it
(which modules are, and how a broken one is refused: ``cellguard.plugins``). Named in one list beside the metrics'
own files, a metric written and tested was unknown to every plan until that list was edited too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from cellguard import plugins
from cellguard.release.evidence import RunEvidence
from cellguard.robot.pick_place import PickPlaceCell


@dataclass(frozen=True)
class Measure:
    value: float | None
    cycles: int
    evidence: tuple[str, ...] = ()


@dataclass(frozen=True)
class Needs:
    """What a cell must have for a metric to have any data: its cycles report what the metric reads."""

    what: str
    cell_type: type

    def met_by(self, cell) -> bool:
        return isinstance(cell, self.cell_type)


PICK_PLACE = Needs("a pick-place task (a part placed in a drop zone: its place error)", PickPlaceCell)


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    compute: Callable[[Sequence[RunEvidence]], Measure]
    hard: bool = False  # a safety count: failure limit 0, decided even on too few cycles
    most: float = float("inf")  # the largest value it can take (every metric is at least 0)
    needs: Needs | None = None  # what the cell must have (None: every cell's runs give it data)
    shadow: bool = False  # measured on shadow runs only (a stage with ``shadow: true``)


def cycles_in(runs) -> int:
    """The cycles ``runs`` hold: how much data a metric over all of them saw."""
    return sum(len(r.cycles) for r in runs)


def percentile(runs, values: list[tuple[float, str]], q: float, unit: str) -> Measure:
    """The ``q`` percentile of the finite ``values`` ((value, where) pairs), naming where the worst was."""
    vals = [(v, where) for v, where in values if np.isfinite(v)]
    if not vals:
        return Measure(None, 0)
    x = np.array([v for v, _ in vals])
    worst = max(vals)
    return Measure(float(np.percentile(x, q)), cycles_in(runs), (f"worst {worst[0]:.3g} {unit} in {worst[1]}",))


METRICS: dict[str, Metric] = {}  # name -> metric, in the order of the modules' names; filled by ``discover``


def discover() -> dict[str, Metric]:
    """Fill ``METRICS`` (in place: the gates hold it) from every module on this package's ``__path__``. A module
    without a tuple of ``Metric`` as ``METRICS`` is refused naming it, and a name two metrics take naming both: a
    second ``success_rate`` would have changed every plan's gate on it unseen."""
    found = plugins.discover(__name__, __path__, _metrics_in, "metric")
    METRICS.clear()
    METRICS.update(found)
    return METRICS


def _metrics_in(module: ModuleType) -> list[tuple[str, str, Metric]]:
    metrics = getattr(module, "METRICS", None)
    if not (isinstance(metrics, tuple) and metrics and all(isinstance(m, Metric) for m in metrics)):
        raise plugins.refused(module, "a metric module defines METRICS, a tuple of Metric")
    return [(m.name, module.__name__, m) for m in metrics]


discover()
