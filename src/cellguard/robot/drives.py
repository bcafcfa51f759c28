"""The joint drives of a MuJoCo cell: position servos, their current sensing, and what faults change.

Any cell whose profiled joints each have a position actuator of the same name uses this: it
maps the profile's joint order onto the model once, reads the state a drive would report
(current = actuator force / torque constant + noise), and sets friction and servo gain as
absolute multiples of the commissioned values, so re-applying a fault is harmless.
"""

from __future__ import annotations

import functools
import sys

import mujoco
import numpy as np

from cellguard.embodiment import Profile
from cellguard.embodiment.kinematics import span
from cellguard.robot.protocol import RobotLinkError, SafetyInputs
from cellguard.robot.state import State


class PositionDrives:
    """The position servos of ``profile``'s joints in ``model``; arrays in profile joint order."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, profile: Profile,
                 rng: np.random.Generator, current_noise: float, brake_damping: float):
        self.model, self.data, self.profile, self.rng = model, data, profile, rng
        self.current_noise = current_noise  # [A] 1-sigma noise of each current reading
        self.brake_damping = brake_damping  # [N·m·s/rad] joint damping while power is off
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in profile.joint_names]
        self.qadr = np.array([model.jnt_qposadr[j] for j in jids])
        self.dadr = np.array([model.jnt_dofadr[j] for j in jids])
        self.act = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in profile.joint_names])
        # read every tick: a slice where the addresses run in order (a view; a fancy index copies and costs more)
        self._q, self._v, self._a = span(self.qadr), span(self.dadr), span(self.act)
        # MjData's arrays stay where they are for its lifetime: fetched once, not per tick
        self._qpos, self._qvel, self._force = data.qpos, data.qvel, data.actuator_force
        self._kt = profile.array("torque_constant")
        self.nominal_frictionloss = model.dof_frictionloss[self.dadr].copy()
        self.nominal_gain = model.actuator_gainprm[self.act, 0].copy()
        self.nominal_bias = model.actuator_biasprm[self.act, 1:3].copy()
        self.nominal_damping = model.dof_damping[self.dadr].copy()

    def read(self, t_ns: int) -> State:
        """What the drives report now: position, velocity, effort and motor current."""
        effort = self._force[self._a].copy()
        current = effort / self._kt + self.rng.normal(0.0, self.current_noise, len(effort))
        return State(t_ns, self._qpos[self._q].copy(), self._qvel[self._v].copy(), effort, current)

    def write(self, setpoint: np.ndarray) -> np.ndarray:
        """Command joint positions; return what the drives took."""
        ctrl = self.data.ctrl
        ctrl[self._a] = setpoint
        return ctrl[self._a].copy()

    def set_power(self, on: bool) -> None:
        """Power off: every actuator disabled and the joints braked (high damping); on: as commissioned."""
        self.model.opt.disableactuator = 0 if on else 1  # the drives are in actuator group 0
        self.model.dof_damping[self.dadr] = self.nominal_damping if on else self.brake_damping

    def set_friction_scale(self, joint: str, factor: float) -> None:
        """Dry friction of ``joint`` = commissioned value x ``factor``."""
        i = self.profile.index(joint)
        self.model.dof_frictionloss[self.dadr[i]] = self.nominal_frictionloss[i] * factor

    def set_servo_gain(self, joint: str, factor: float) -> None:
        """Position and velocity gains of ``joint``'s servo = commissioned values x ``factor``."""
        i = self.profile.index(joint)
        self.model.actuator_gainprm[self.act[i], 0] = self.nominal_gain[i] * factor
        self.model.actuator_biasprm[self.act[i], 1:3] = self.nominal_bias[i] * factor


# MuJoCo's checks of the state: what each found bad (it then resets the state)
QPOS, QVEL, QACC = (int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                     mujoco.mjtWarning.mjWARN_BADQACC))
BAD_STATE = {QPOS: "position", QVEL: "velocity", QACC: "acceleration"}


def _warn(message: str) -> None:
    """MuJoCo's warnings on stderr: by default it also appended them to MUJOCO_LOG.TXT in whatever folder the
    process ran in (a user's working folder, the repository under the tests)."""
    sys.stderr.write(f"MuJoCo: {message}\n")


mujoco.set_mju_user_warning(_warn)


class DrivenCell:
    """The Robot calls of a MuJoCo cell whose joints are ``PositionDrives``; a cell adds its task.

    The cell sets ``model``, ``data``, ``drives`` and ``safety_inputs`` (what its simulated
    certified safety controller says; scenarios and tests set it).
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    drives: PositionDrives
    safety_inputs: SafetyInputs
    unstable: str | None = None  # why the physics stopped being a robot (set by ``physics_step``)

    @property
    def t_ns(self) -> int:
        return round(self.data.time * 1e9)

    def physics_step(self) -> None:
        """One ``mj_step``. MuJoCo resets a state gone NaN, Inf or huge (its time back to 0) and carries on: the run
        went on with time gone back and wrote a record its readers call damaged (ticks repeating sequence numbers),
        exit 0. Here time keeps running and every later read fails, the link lost: the run stops, named."""
        before = self.data.time
        mujoco.mj_step(self.model, self.data)
        counts = self._warning_counts
        if counts[QPOS] or counts[QVEL] or counts[QACC]:  # one look a step: indexing ``data.warning`` cost 3 µs
            self._unstable_since(before)

    @functools.cached_property
    def _warning_counts(self) -> np.ndarray:
        """A live view of MuJoCo's warning counters (the cell's one MjData, kept for its life)."""
        return self.data.warning.number

    def _unstable_since(self, before: float) -> None:
        """Name the first blow-up (what went bad, where) and keep time running from ``before`` [s]."""
        if self.unstable is None:
            warning = next(w for w in BAD_STATE if self.data.warning[w].number)
            self.unstable = (f"the simulation became unstable at {before:.3f} s: MuJoCo found a NaN, Inf or huge "
                             f"{BAD_STATE[warning]} of DOF {self.data.warning[warning].lastinfo} and reset its state "
                             f"(the cell's physics, not a robot fault: see the scenario's faults and process changes)")
        self.data.time = max(self.data.time, before + self.model.opt.timestep)

    def read(self) -> State:
        if self.unstable is not None:
            raise RobotLinkError("robot_read_failed", self.unstable, lost=True)
        return self.drives.read(self.t_ns)

    def write(self, setpoint: np.ndarray) -> np.ndarray:
        return self.drives.write(setpoint)

    def safety(self) -> SafetyInputs:
        return self.safety_inputs

    def set_power(self, on: bool) -> None:
        """Power off: the actuators are disabled and the joint brakes (high damping) engage."""
        self.drives.set_power(on)

    def set_friction_scale(self, joint: str, factor: float) -> None:
        self.drives.set_friction_scale(joint, factor)

    def set_servo_gain(self, joint: str, factor: float) -> None:
        self.drives.set_servo_gain(joint, factor)
