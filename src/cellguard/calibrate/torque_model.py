"""The joint torque a cell's model needs for a measured motion: nominal, or with identified parameters.

``tau = ID_rigid(q, qd, qdd) + (armature + dt (kv + damping)) qdd + damping qd + friction sign(qd)``
per hinge joint, the rigid part from ``mj_inverse`` on the model with armature, damping, dry friction
and constraints removed (a payload, when identified, added to the tool body's mass). ``qdd`` is the
finite difference of measured velocity over one servo step, as the implicit integrator sees it (it
adds ``dt (kv + damping)`` to the effective inertia). The same formula is what ``identify`` fits, so
a prediction uses the fit's own terms. Measured torque is current x torque constant.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

MIN_SPEED = 0.05  # below this speed dry friction is set-valued: such samples are not compared [rad/s]
SMOOTH_TICKS = 20  # moving average over which predicted and measured current are compared [ticks]


def hinge_joints(cell) -> list[int]:
    """Profile indices of the joints a dynamic model covers (hinges; grippers and slides are left out)."""
    return [i for i, j in enumerate(cell.profile.joints) if j.kind == "hinge"]


def rigid_model(model: mujoco.MjModel, payload_kg: float = 0.0) -> mujoco.MjModel:
    """``model`` with only rigid-body dynamics left (no armature, damping, dry friction, constraints);
    ``payload_kg`` added at the ``tool`` body's centre of mass."""
    rigid = copy.deepcopy(model)
    rigid.dof_armature[:] = 0.0
    rigid.dof_damping[:] = 0.0
    rigid.dof_frictionloss[:] = 0.0
    rigid.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    if payload_kg:
        rigid.body_mass[mujoco.mj_name2id(rigid, mujoco.mjtObj.mjOBJ_BODY, "tool")] += payload_kg
    return rigid


def inverse_torques(rigid: mujoco.MjModel, cell, q: np.ndarray, qd: np.ndarray, dt: float,
                    steps: np.ndarray | None = None) -> np.ndarray:
    """Rigid-body torques (n-1, hinge joints) [N*m] at each step's start state (q, qd (n, dof)) and the
    acceleration over the step; only at ``steps`` (indices into the n-1 steps) if given. The rest of the
    model (tool, part, a base on its stand) stays where the cell holds it, at rest."""
    joints = hinge_joints(cell)
    qadr, dadr = cell.drives.qadr, cell.drives.dadr
    d = mujoco.MjData(rigid)
    d.qpos[:] = cell.data.qpos
    acc = np.diff(qd, axis=0) / dt
    steps = np.arange(len(q) - 1) if steps is None else steps
    tau = np.empty((len(steps), len(joints)))
    out = dadr[joints]
    for i, k in enumerate(steps):
        d.qpos[qadr] = q[k]
        d.qvel[:] = 0.0
        d.qvel[dadr] = qd[k]
        d.qacc[:] = 0.0
        d.qacc[dadr] = acc[k]
        mujoco.mj_inverse(rigid, d)
        tau[i] = d.qfrc_inverse[out]
    return tau


@dataclass(frozen=True)
class JointTerms:
    """Per hinge joint (nj,): armature [kg*m^2], damping [N*m*s/rad], dry friction [N*m]; payload [kg]."""

    armature: np.ndarray
    damping: np.ndarray
    friction: np.ndarray
    payload_kg: float = 0.0

    @classmethod
    def nominal(cls, cell) -> JointTerms:
        dadr = cell.drives.dadr[hinge_joints(cell)]
        m = cell.model
        return cls(m.dof_armature[dadr].copy(), m.dof_damping[dadr].copy(), m.dof_frictionloss[dadr].copy())

    @classmethod
    def from_estimates(cls, cell, estimates: list[dict]) -> JointTerms:
        """The nominal terms with every identified value of ``estimates`` (identify's rows) put in."""
        base = cls.nominal(cell)
        names = [cell.profile.joint_names[i] for i in hinge_joints(cell)]
        arrays = {"armature": base.armature.copy(), "damping": base.damping.copy(), "friction": base.friction.copy()}
        payload = 0.0
        for e in estimates:
            if e.get("interval") is None:
                continue
            if e["parameter"] in arrays and e["joint"] in names:
                arrays[e["parameter"]][names.index(e["joint"])] = e["value"]
            elif e["parameter"] == "payload":
                payload = float(e["value"])
        return cls(payload_kg=payload, **arrays)

    @classmethod
    def from_profile(cls, cell, path=None, option: str = "--profile") -> JointTerms:
        """The calibrated terms: the measured friction, damping and armature of the profile at ``path``
        (``identify --write``'s, given as ``option``; default the cell's own) over the nominal model, and the
        payload its calibration put into the calibrated MJCF."""
        from cellguard.calibrate.mjcf import calibrated_payload
        from cellguard.embodiment import load_profile

        if path is None:
            return cls.of_profile(cell, cell.profile)
        # another robot's is refused as such before its limits are checked against this model
        profile = load_profile(cell.model, path, cell.profile.robot)
        return cls.of_profile(cell, profile, calibrated_payload(path, profile, cell.model, option))

    @classmethod
    def of_profile(cls, cell, profile, payload_kg: float = 0.0) -> JointTerms:
        """``profile``'s measured friction, damping and armature over the nominal terms; ``payload_kg`` [kg]."""
        rows = [{"parameter": m.parameter, "joint": m.joint, "value": m.value, "interval": [m.value, m.value]}
                for m in profile.measured if m.parameter in ("friction", "damping", "armature")]
        rows.append({"parameter": "payload", "joint": None, "value": payload_kg, "interval": [payload_kg, payload_kg]})
        return cls.from_estimates(cell, rows)


class TorqueModel:
    """Predicts the measured joint torque of ``cell``'s hinge joints for a measured motion."""

    def __init__(self, cell, terms: JointTerms | None = None):
        self.cell = cell
        self.terms = terms if terms is not None else JointTerms.nominal(cell)
        self.joints = hinge_joints(cell)
        self.names = tuple(cell.profile.joint_names[i] for i in self.joints)
        self.dt = float(cell.model.opt.timestep)
        self.rigid = rigid_model(cell.model, self.terms.payload_kg)
        act = cell.drives.act[self.joints]
        kv = -cell.model.actuator_biasprm[act, 2]
        self.inertia = self.terms.armature + self.dt * (kv + self.terms.damping)  # effective, per step
        self.torque_constant = cell.profile.array("torque_constant")[self.joints]

    def torque(self, q: np.ndarray, qd: np.ndarray, steps: np.ndarray | None = None) -> np.ndarray:
        """Torque (n-1, nj) [N*m] the model needs over each step of the measured q, qd (n, dof); only at
        ``steps`` (indices into the n-1 steps) if given."""
        j = self.joints
        steps = np.arange(len(q) - 1) if steps is None else steps
        acc = (qd[steps + 1][:, j] - qd[steps][:, j]) / self.dt
        v = qd[steps][:, j]
        t = self.terms
        return (inverse_torques(self.rigid, self.cell, q, qd, self.dt, steps) + self.inertia * acc
                + t.damping * v + t.friction * np.sign(v))

    def current(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Motor current (n-1, nj) [A] the model predicts: torque / torque constant."""
        return self.torque(q, qd) / self.torque_constant


def smooth(x: np.ndarray, ticks: int = SMOOTH_TICKS) -> np.ndarray:
    """Moving average over ``ticks`` along axis 0 of (n, k), the same length (the ends averaged over less)."""
    kernel = np.ones(ticks)
    c = np.array([np.convolve(col, kernel, mode="same") for col in x.T]).T
    return c / np.convolve(np.ones(len(x)), kernel, mode="same")[:, None]


def current_nrmse(model: TorqueModel, segments) -> np.ndarray:
    """Per hinge joint (nj,): RMS of the predicted minus the measured current over the measured current's
    standard deviation, over ticks where the joint moves faster than ``MIN_SPEED``, pooled over
    ``segments`` (contiguous stretches, identify's ``Segment``). Both are smoothed over ``SMOOTH_TICKS``
    first: the current sensor's white noise is no model error, and a model error lies at the motion's
    frequencies, far below 1 / 20 ms. Torque ratios equal current ratios (one constant per joint)."""
    j = model.joints
    pred = np.concatenate([smooth(model.torque(s.q, s.qd)) for s in segments])
    meas = np.concatenate([smooth(s.tau[1:, j]) for s in segments])
    speed = np.abs(np.concatenate([s.qd[:-1, j] for s in segments]))
    out = np.full(len(j), np.nan)
    for k in range(len(j)):
        moving = speed[:, k] > MIN_SPEED
        if moving.sum() > 10:
            m = meas[moving, k]
            out[k] = np.sqrt(np.mean((pred[moving, k] - m) ** 2)) / max(float(np.std(m)), 1e-12)
    return out
