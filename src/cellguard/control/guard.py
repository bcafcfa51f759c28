"""Guard: the executor, the envelope and the speed scale behind one call per servo tick.

The runtime loop, the benchmarks, the tests and a shadow guard (a release candidate that never
actuates) all drive the guard layer the same way: ``push`` a chunk when it arrives, ``tick``
once per servo period. ``reference`` keeps the last reference for the record.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from cellguard.control.config import GuardConfig
from cellguard.control.envelope import NO_INPUTS, Envelope
from cellguard.control.events import Event
from cellguard.control.executor import Executor, PreparedChunk
from cellguard.embodiment import Profile
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.protocol import SafetyInputs

LOOKAHEAD_NS = 300_000_000  # the envelope slows down for tool speed this far ahead [ns]


class Guard:
    """One guard layer: chunks in (``push``), one setpoint per servo tick out (``tick``).

    ``tool``: joint positions (D,) -> tool point (3,) [m], for the box and the tool-speed cap.
    """

    def __init__(self, profile: Profile, q0: np.ndarray, dt_ns: int, config: GuardConfig | None = None,
                 tool: Callable[[np.ndarray], np.ndarray] | None = None):
        config = config or GuardConfig()
        self.config, self.tool = config, tool
        # the playback clock advances one period per tick at most: a late tick lags, never jumps
        self.executor = Executor(profile, q0, dt_ns, blend_ns=round(config.blend_s * 1e9), tool=tool,
                                 max_tick_ns=dt_ns)
        self.envelope = Envelope(profile, q0, dt_ns, config, tool=tool)
        self.reference = np.array(q0, dtype=np.float64)
        self._speed_ahead = partial(self.executor.tool_speed_ahead, LOOKAHEAD_NS)  # asked only under a speed cap

    def push(self, chunk: ActionChunk | PreparedChunk, t_ns: int) -> list[Event]:
        """Swap in a chunk that arrived at ``t_ns``; events for a refused chunk or dropped steps."""
        return self.executor.push(chunk, t_ns)

    def tick(self, t_ns: int, state=None, safety: SafetyInputs = NO_INPUTS) -> tuple[np.ndarray, list[Event]]:
        """The setpoint (D,) to send this tick and the events raised; never raises on bad values."""
        executor, envelope = self.executor, self.envelope
        self.reference = executor.reference(t_ns, envelope.scale)
        return envelope.apply(t_ns, self.reference, state, safety, executor.last_chunk_ns, executor.uncertainty,
                              self._speed_ahead)

    @property
    def power(self) -> bool:
        """False after a category 0 or 1 stop removed drive power."""
        return self.envelope.power

    @property
    def stop(self) -> tuple[int, str] | None:
        """The stop in force, (category, reason), or None."""
        envelope = self.envelope
        return None if envelope.stop_category is None else (envelope.stop_category, envelope.stop_reason)

    def reset(self, q: np.ndarray) -> None:
        """Operator reset after a stop: power on, standstill at the measured ``q``."""
        self.envelope.reset(q)
