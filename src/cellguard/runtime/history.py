"""The run's events and cycle outcomes in bounded memory: a window in memory, the rest in the record.

A run that never ends (a production cell) would otherwise grow both lists without bound. The
record keeps every event and cycle; these windows keep the newest ones for the summary and
the loop, and count the rest.
"""

from __future__ import annotations

from collections import deque

EVENT_WINDOW = 10_000
CYCLE_WINDOW = 10_000


class EventLog:
    """Events with absolute indices: ``len`` counts every event ever appended; iteration and
    slices see the ones still in the window (``log[i:]`` from absolute index ``i``)."""

    def __init__(self, window: int = EVENT_WINDOW):
        self._items: deque = deque(maxlen=window)
        self.total = 0

    def append(self, event) -> None:
        self._items.append(event)
        self.total += 1

    def extend(self, events) -> None:
        for event in events:
            self.append(event)

    def __len__(self) -> int:
        return self.total

    def __iter__(self):
        return iter(self._items)

    def __eq__(self, other) -> bool:
        return list(self._items) == list(other) if isinstance(other, (list, EventLog)) else NotImplemented

    __hash__ = None

    def __getitem__(self, index):
        if isinstance(index, slice):
            if index.step not in (None, 1) or index.stop is not None:
                raise IndexError("EventLog slices are [start:] only")
            return self.since(index.start or 0)
        first = self.total - len(self._items)
        i = index + self.total if index < 0 else index
        if not first <= i < self.total:
            raise IndexError(f"event {index} is no longer in memory (kept: {first}..{self.total - 1})")
        return self._items[i - first]

    def since(self, start: int) -> list:
        """Events from absolute index ``start`` on (those still in the window)."""
        first = self.total - len(self._items)
        skip = max(0, start - first)
        return [e for i, e in enumerate(self._items) if i >= skip]

    def has(self, kind: str) -> bool:
        return any(e.kind == kind for e in self._items)


class CycleWindow(list):
    """The newest cycle outcomes (between ``window`` and 1.1 x ``window`` of them), and per-phase
    counts over the whole run."""

    def __init__(self, window: int = CYCLE_WINDOW):
        super().__init__()
        self.window = window
        self.total = 0
        self._counts = {"acceptance": [0, 0], "production": [0, 0]}  # cycles, successes

    def append(self, outcome: dict) -> None:
        super().append(outcome)
        if len(self) > self.window * 1.1:
            del self[:len(self) - self.window]
        self.total += 1
        count = self._counts[outcome["phase"]]
        count[0] += 1
        count[1] += bool(outcome["success"])

    def phases(self) -> dict:
        return {phase: {"cycles": n, "success_rate": ok / n if n else None} for phase, (n, ok) in self._counts.items()}
