"""One row per cycle, whatever its source: the runner's outcomes, the record reader, a test.

Diagnosis is a pure function of these rows, the events and the context, so it reads a
record written months ago the same way it reads a run still in memory.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from cellguard.errors import RecordError

LABELS = ("direction",)  # text fields of an outcome that name the motion (mirrored cells)


@dataclass(frozen=True)
class Cycle:
    """A cycle's index, phase (``acceptance`` or ``production``), success and flat features."""

    index: int
    phase: str
    success: bool
    features: Mapping[str, float]
    t_start_ns: int | None = None
    t_end_ns: int | None = None
    labels: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def label(self) -> str | None:
        """The motion this cycle performed (``left``/``right`` on a mirrored cell), if any."""
        return self.labels.get("direction")


def getter(item: object):
    """``item``'s fields by name, ``get(name, default=None)``: a mapping's keys or an object's attributes (a run's
    rows are mappings, a record's cycles and events objects)."""
    return item.get if isinstance(item, Mapping) else (lambda k, d=None: getattr(item, k, d))


def as_cycle(row: object) -> Cycle:
    """A Cycle from a mapping or an object with the same names (``cycle`` or ``index``)."""
    if isinstance(row, Cycle):
        return row
    get = getter(row)
    index = get("cycle", get("index"))
    features = get("features")
    if index is None or not isinstance(features, Mapping):
        raise RecordError(f"cycle row: needs 'cycle' and a 'features' mapping, got {type(row).__name__}")
    outcome = get("outcome") if isinstance(get("outcome"), Mapping) else {}
    labels = {k: v for k in LABELS for v in (get(k, outcome.get(k)),) if isinstance(v, str)}
    return Cycle(
        index=int(index),
        phase=str(get("phase", "production")),
        success=bool(get("success", features.get("success", True))),
        features=MappingProxyType({k: float(v) for k, v in features.items() if _numeric(v)}),
        t_start_ns=get("t_start_ns"),
        t_end_ns=get("t_end_ns"),
        labels=MappingProxyType(labels),
    )


def as_cycles(rows: Iterable[object]) -> list[Cycle]:
    """Cycles sorted by index."""
    return sorted((as_cycle(r) for r in rows), key=lambda c: c.index)


def _numeric(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, complex)
