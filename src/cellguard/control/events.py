"""Events: every intervention of the guard layer, with what was asked, what was sent and why.

``EventKind`` is the one list of event kinds, each with whether it is routine (normal
bookkeeping: no full-rate record window, not a safety event in a diagnosis), the stop
category it carries, if it is a stop, and whether the run stops after it (``ends_run``).
The values are the strings written into records and the ``diagnose --json`` contract: add
kinds, never rename them. ``EventKind`` is a ``str``, so a kind compares equal to its string
and serialises as it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum


class EventKind(StrEnum):
    """What happened; ``routine``, ``category`` (IEC 60204-1, None: not a stop of its own) and ``ends_run`` (the run
    stops after it: a cycle it falls in was cut short, not completed) per kind."""

    def __new__(cls, value: str, routine: bool = False, category: int | None = None, ends_run: bool = False):
        member = str.__new__(cls, value)
        member._value_ = value
        member.routine, member.category, member.ends_run = routine, category, ends_run
        return member

    # executor: chunks in
    CHUNK_REJECTED = "chunk_rejected"
    CHUNK_STALE = "chunk_stale"
    CHUNK_STEPS_DROPPED = "chunk_steps_dropped", True
    CHUNK_RAN_OUT = "chunk_ran_out"  # the chunk in use ended before the next arrived: the reference held its end
    # envelope: stops (category None: the category is the request's, e.g. the safety input's)
    PROTECTIVE_STOP = "protective_stop"
    REFERENCE_INVALID = "reference_invalid", False, 2
    EFFORT_LIMIT = "effort_limit"
    EFFORT_STOP = "effort_stop", False, 2
    WATCHDOG_STOP = "watchdog_stop"
    UNCERTAINTY_HOLD = "uncertainty_hold", False, 2
    WORKSPACE_STOP = "workspace_stop", False, 2
    POWER_REMOVED = "power_removed"
    RESUME = "resume"
    # envelope: limits and lasting conditions
    LIMIT_INTERVENTION = "limit_intervention"
    LIMIT_BRAKE = "limit_brake"
    TRACKER_FAILED = "tracker_failed"
    REDUCED_SPEED_INPUT = "reduced_speed_input"
    REDUCED_SPEED_INPUT_CLEARED = "reduced_speed_input_cleared"
    UNCERTAINTY_GATE = "uncertainty_gate"
    UNCERTAINTY_GATE_CLEARED = "uncertainty_gate_cleared"
    # the loop
    RESET = "reset"
    INFERENCE_FAILED = "inference_failed"
    # its process ended, a call hung or every answer before a chunk refused: the run ends
    POLICY_LOST = "policy_lost", False, None, True
    # a start-up check refused to move (or the warm-up never answered): StartupRefused ends the run
    STARTUP_REFUSED = "startup_refused", False, None, True
    RECORD_FAILED = "record_failed", False, 2, True
    RECORD_QUEUE_FULL = "record_queue_full"
    # the cycle's tick buffer could not grow (out of memory): the cycle has no tick features; the run goes on. The
    # host's, no safety event and no intervention: routine (no full-rate window opened where memory ran out)
    CYCLE_BUFFER_FULL = "cycle_buffer_full", True
    # the run goes on (a late first chunk starts it); a stop that removes a bridged robot's power ends it, whatever
    # asked it (power_removed, as a limit's stop does)
    WATCHDOG_NO_FIRST_CHUNK = "watchdog_no_first_chunk"
    OPERATOR_STOP = "operator_stop", False, 2, True  # Ctrl-C, SIGTERM or SIGHUP while the cycles run
    # written by the recorder alone: the run's process died (SIGKILL, OOM)
    RUN_PROCESS_LOST = "run_process_lost", False, None, True
    # the real-time loop: ticks later than one period, and the budget that stops the cell
    OVERRUN = "overrun"
    OVERRUN_BUDGET = "overrun_budget", False, None, True  # a robot link fault (the loop's _overrun): the run ends
    # safe transitions: the approach to the policy's first target, the retreat to home
    APPROACH_BEGIN = "approach_begin", True
    APPROACH_DONE = "approach_done", True
    APPROACH_ABORTED = "approach_aborted"
    RETREAT_BEGIN = "retreat_begin", True
    RETREAT_DONE = "retreat_done", True
    RETREAT_ABORTED = "retreat_aborted"
    # recoveries: a behaviour run in place of the policy after a failed check (reason: behaviour, trigger,
    # attempt; at the end also duration, arrival at contact and outcome: resumed, failed, escalated,
    # gave_up, cut_off; as words and as the event's recovery)
    RECOVERY_START = "recovery_start", True
    RECOVERY_END = "recovery_end", True
    # the robot link (category: the scenario's realtime.stop_category); each ends the run
    ROBOT_READ_FAILED = "robot_read_failed", False, None, True
    ROBOT_READ_TIMEOUT = "robot_read_timeout", False, None, True
    ROBOT_STATE_STALE = "robot_state_stale", False, None, True
    ROBOT_PACKETS_DROPPED = "robot_packets_dropped", False, None, True
    ROBOT_WRITE_FAILED = "robot_write_failed", False, None, True
    ROBOT_SERVER_GONE = "robot_server_gone", False, None, True


ROUTINE_EVENTS = frozenset(k.value for k in EventKind if k.routine)  # kinds that are normal bookkeeping
# kinds that are no intervention of the guard's: a chunk that ran out is the policy's timing, told beside the braking
# that follows it (counted too, it doubled interventions_per_hour and the interventions feature for the same motion)
NO_INTERVENTION = ROUTINE_EVENTS | {EventKind.CHUNK_RAN_OUT.value}


@dataclass(frozen=True)
class Event:
    """One intervention or incident. ``category`` is the IEC 60204-1 stop category, if a stop. ``recovery``: a
    ``recovery_end``'s attempt as fields (``RecoveryOutcome.to_dict``, None values left out), recorded with the
    event when the attempt ends, so a record its run was killed in still holds the attempts of its last cycle."""

    t_ns: int
    kind: str  # an EventKind (a str); a reader may meet kinds this version does not know
    reason: str
    joint: str | None = None
    asked: float | None = None
    sent: float | None = None
    category: int | None = None
    recovery: dict | None = field(default=None, hash=False)  # a dict: an event stays hashable

    def to_dict(self) -> dict:
        return {k: (str(v) if k == "kind" else v) for k, v in self.__dict__.items() if v is not None}
