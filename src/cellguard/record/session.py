"""The recorder as the runner uses it: fed from the tick loop, never raising into it.

A write error ends the recording for good and sets ``failed``; the runner reads it after each tick
and stops the cell (category 2) because an unrecorded run is not allowed.
"""

from __future__ import annotations

from pathlib import Path

from cellguard.errors import RecordError
from cellguard.record.context import build_context, software_versions
from cellguard.record.index import default_opener
from cellguard.record.writer import RecordConfig, Recorder


class RunRecording:
    """One run's record: context per cycle, measurements, chunks, ticks, events, cycle ends."""

    def __init__(self, recorder: Recorder, run):
        self.recorder, self.run = recorder, run
        self.failed: str | None = None
        self._events_seen = len(run.events)
        self._software = software_versions()
        self._cycle = 0

    @classmethod
    def start(cls, folder: Path, run, config: RecordConfig = RecordConfig(), opener=default_opener) -> RunRecording:
        """Open the record of ``run`` in ``folder``; RecordError (nothing runs) if it cannot be written."""
        context = cls._context(run, config, software_versions())
        recorder = Recorder.create(folder, joints=run.cell.profile.joint_names, dt_ns=run.cell.dt_ns,
                                   context=context, config=config, opener=opener)
        return cls(recorder, run)

    @staticmethod
    def _context(run, config: RecordConfig, software: dict) -> dict:
        context = build_context(scenario=run.scenario, cell=run.cell, policy=run.policy, envelope=run.guard.envelope,
                                software=software)
        release = getattr(run, "release", None)  # set by cellguard.release: the release and any pointer switch
        return {**context, **({"release": release} if release else {}), "record": config.to_dict()}

    def begin_cycle(self, cycle: int, phase: str, t_ns: int) -> None:
        self._cycle = cycle
        self._do(self.recorder.set_context, self._context(self.run, self.recorder.config, self._software), t_ns)
        self._do(self.recorder.cycle_begin, cycle, phase, t_ns)

    def request(self, t_ns: int, observation) -> None:
        self._do(self.recorder.measurements, t_ns, self._cycle, observation.measurements)

    def chunk(self, chunk, t_ns: int, latency_ns: int) -> None:
        self._do(self.recorder.chunk, chunk, t_ns, latency_ns)

    def tick(self, reference, sent, state) -> bool:
        """Record the tick and any new events; False once recording has failed."""
        if len(self.run.events) > self._events_seen:
            self.events()
        self._do(self.recorder.tick, self._cycle, reference, sent, state)
        return self.failed is None

    def end_cycle(self, outcome: dict, t_ns: int) -> None:
        self.events()
        self._do(self.recorder.cycle_end, outcome, t_ns)

    def events(self) -> None:
        """Record the run's events not recorded yet."""
        events = self.run.events
        for event in events[self._events_seen:]:
            self._do(self.recorder.event, event, self._cycle)
        self._events_seen = len(events)

    def close(self) -> None:
        """Finish the file; after a failure only the handle is closed (nothing written is touched)."""
        try:
            self.recorder.close()
        except RecordError as exc:
            self.failed = self.failed or str(exc)

    def _do(self, fn, *args) -> None:
        if self.failed is not None:
            return
        try:
            fn(*args)
        except RecordError as exc:
            self.failed = str(exc)
