"""A recovery behaviour: what the cell does when one of its checks fails, instead of simply ending the cycle.

A behaviour is a validated value (pydantic, unknown keys refused) that turns the cell's state
at the failure into a ``Plan``: timed joint waypoints the runtime feeds through the guard as
action chunks, in place of the policy. ``needs`` names the cell methods a behaviour calls; a cell
without them cannot run it, and the scenario is refused before anything moves.

Common keys: ``trigger`` the failed check that starts it (none: only reached by escalation),
``attempts`` how many times it is tried in one cycle, ``then`` the behaviour it escalates to
when every attempt failed, ``speed_scale`` its share of the taught speed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field


class PlanError(Exception):
    """A plan no behaviour means to make: a behaviour's bug (a plugin's), told apart from a pose the arm cannot
    reach (ValueError); the runner logs it and gives up on the attempt as on one it cannot plan."""


@dataclass(frozen=True)
class Plan:
    """Timed waypoints of one recovery; the arm and the gripper on separate tracks.

    ``arm_t`` (N,) [s] with ``arm_q`` (N, dof-1) [rad or m]; ``grip_t`` (M,) [s] with ``grip_q`` (M,)
    in the gripper joint's unit. Between waypoints a minimum-jerk blend. ``contact_q`` (dof-1,) is
    the arm pose where the tool meets the part, ``close_t`` [s] when the gripper is told to shut
    there (None for a plan with no contact); ``hold_s`` [s] a stop with power kept at the start
    (an operator hand-over).
    """

    arm_t: np.ndarray
    arm_q: np.ndarray
    grip_t: np.ndarray
    grip_q: np.ndarray
    contact_q: np.ndarray | None = None
    close_t: float | None = None
    hold_s: float = 0.0

    def __post_init__(self):
        """Refuse a plan the loop cannot follow: a number that is not finite reached the guard as a target, or
        (``close_t``) hid the attempt from the diagnosis, which leaves out a log entry of times not finite; tracks
        that are empty, out of time order or given as lists ended the run in a traceback when sampled. The tracks
        are kept as float arrays."""
        for name in ("arm_t", "arm_q", "grip_t", "grip_q", "contact_q"):
            value = getattr(self, name)
            if value is not None:
                try:
                    object.__setattr__(self, name, np.asarray(value, dtype=np.float64))
                except (TypeError, ValueError):
                    raise PlanError(f"its {name} is not an array of numbers") from None
        for name in ("arm_t", "arm_q", "grip_t", "grip_q", "contact_q", "close_t", "hold_s"):
            value = getattr(self, name)
            if value is not None and not np.isfinite(np.asarray(value, dtype=np.float64)).all():
                raise PlanError(f"its {name} is not finite")
        for name in ("arm_t", "grip_t"):
            times = getattr(self, name)
            if times.ndim != 1 or not len(times) or (np.diff(times) < 0).any():
                raise PlanError(f"its {name} is not one or more times in order")
        if self.arm_q.ndim != 2 or len(self.arm_q) != len(self.arm_t):
            raise PlanError(f"its arm_q is not {len(self.arm_t)} poses, one per arm_t")
        if self.grip_q.shape != self.grip_t.shape:
            raise PlanError(f"its grip_q is not {len(self.grip_t)} values, one per grip_t")

    def duration(self, arm_speed: float = 1.0) -> float:
        """Length of the plan [s] when the arm runs at ``arm_speed`` of its plan (the gripper keeps its own)."""
        return self.hold_s + max(float(self.arm_t[-1]) / arm_speed, float(self.grip_t[-1]))

    def sample(self, t: np.ndarray, arm_speed: float = 1.0) -> np.ndarray:
        """Targets (len(t), dof) at plan times ``t`` [s]; the arm at ``arm_speed`` of its plan."""
        t = np.asarray(t, dtype=np.float64) - self.hold_s
        arm = _blend(self.arm_t, self.arm_q, t * arm_speed)
        grip = _blend(self.grip_t, self.grip_q[:, None], t)
        return np.hstack([arm, grip])


def _blend(times: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    if len(times) == 1:
        return np.repeat(poses[:1], len(t), axis=0)
    k = np.clip(np.searchsorted(times, t, side="right"), 1, len(times) - 1)
    u = np.clip((t - times[k - 1]) / np.maximum(times[k] - times[k - 1], 1e-9), 0.0, 1.0)
    s = (u * u * u * (10.0 - 15.0 * u + 6.0 * u * u))[:, None]
    return poses[k - 1] + s * (poses[k] - poses[k - 1])


class Recovery(BaseModel):
    """Base of every recovery behaviour; ``do`` is the discriminator in scenario files."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    needs: ClassVar[tuple[str, ...]] = ()  # cell methods the behaviour calls
    trigger: str | None = Field(default=None, description="the failed check that starts it (one of the cell's "
                                                            "failure_checks)")
    attempts: int = Field(default=1, ge=1, le=20, description="tries in one cycle before it escalates")
    then: str | None = Field(default=None, description="the behaviour it escalates to")
    speed_scale: float = Field(default=1.0, gt=0.05, le=1.0, description="share of the taught speed")

    def plan(self, cell, q: np.ndarray, attempt: int, origin: np.ndarray) -> Plan:
        """The recovery's waypoints from the reference ``q`` (dof,) at its start; ``attempt`` counts from 1;
        ``origin`` (dof,) is the reference when the check first failed (the policy's own grasp)."""
        raise NotImplementedError


def pick_and_finish(cell, q: np.ndarray, target: np.ndarray, speed_scale: float) -> Plan:
    """Open, lift, go above ``target`` [m] (tool point, world), descend, shut, then carry to the drop
    zone, release and go home: the rest of the cycle, re-done from a new grasp. Times at ``speed_scale``."""
    up = np.array([0.0, 0.0, cell.approach_height])
    drop = cell.drop_point()
    arm = q[:-1]
    above, pick = cell.reach(target + up, arm), cell.reach(target, arm)
    above_drop, at_drop = cell.reach(drop + up, above), cell.reach(drop, above)
    home = np.asarray(cell.q_home[:-1], dtype=np.float64)
    lift_now = lift(cell, arm)
    g_open, g_shut = cell.gripper_open, cell.gripper_shut
    s = 1.0 / speed_scale
    arm_steps = [(0.0, arm), (0.25, arm), (0.65, lift_now), (1.15, above), (1.65, pick), (2.15, pick),
                 (2.55, above), (3.35, above_drop), (3.75, at_drop), (3.95, at_drop), (4.25, above_drop),
                 (4.95, home)]
    grip_steps = [(0.0, q[-1]), (0.25, g_open), (1.8, g_open), (2.05, g_shut), (3.95, g_shut), (4.15, g_open)]
    return Plan(np.array([t * s for t, _ in arm_steps]), np.array([p for _, p in arm_steps]),
                np.array([t * s for t, _ in grip_steps]), np.array([g for _, g in grip_steps], dtype=np.float64),
                contact_q=pick, close_t=1.8 * s)


def lift(cell, arm: np.ndarray) -> np.ndarray:
    """Arm joints (dof-1,) with the tool ``approach_height`` straight above where it is at ``arm``; ValueError
    where the arm cannot keep its tool down there (an SO-101 already at its approach height over the drop zone)."""
    return cell.reach(cell.tool_taught(arm) + [0.0, 0.0, cell.approach_height], arm)


def go_home(cell, q: np.ndarray, speed_scale: float, hold_s: float = 0.0) -> Plan:
    """Open the gripper, lift the tool, and go home (a held part is let go where it is). Times at ``speed_scale``.
    It cannot fail: where the arm cannot lift its tool straight up it goes home in joint space from where it is
    (the last resort after a plan that failed, the same IK among them, must still get the arm home)."""
    s = 1.0 / speed_scale
    home = np.asarray(cell.q_home[:-1], dtype=np.float64)
    arm = q[:-1]
    try:
        up = lift(cell, arm)
    except ValueError:
        up = arm
    return Plan(np.array([0.0, 0.3 * s, 0.8 * s, 1.6 * s]), np.array([arm, arm, up, home]),
                np.array([0.0, 0.3 * s]), np.array([q[-1], cell.gripper_open], dtype=np.float64), hold_s=hold_s)
