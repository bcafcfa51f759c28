"""Replay a record's commands on the cell's own model with identified values: data whose truth is known.

``identify`` re-fits this replay to measure its own bias (``identify.method_bias``): the same
commands, the same servo period and integrator, the same start states, the model's armature,
damping, dry friction, servo gain and payload set to the identified values, the drives acting
``lag`` ticks late. Only the joints' inputs are replayed, so a base that floats is held as on a
stand (and contacts are off: on a stand nothing touches), and a fixed-base cell's other bodies
(a part on a table) start where the cell holds them.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import mujoco
import numpy as np

from cellguard.calibrate.torque_model import hinge_joints


def simulate(segments: list, cell, lag: int, values: dict) -> list:
    """``segments`` (identify's ``Segment``) with q, qd and tau replaced by a noise-free replay of their
    commands: row ``j + 1`` is the state one ``mj_step`` after row ``j`` with the command of row
    ``j + 1 - lag`` acting, and the drives' effort over that step [N*m]. ``values``
    {(parameter, joint): value} from the fit (armature, damping, friction, kp per hinge joint; payload
    under ("payload", None) if fitted)."""
    model = _model(cell, values)
    qadr, dadr, act = cell.drives.qadr, cell.drives.dadr, cell.drives.act
    out = []
    for s in segments:
        data = mujoco.MjData(model)
        data.qpos[:] = cell.data.qpos
        data.qpos[qadr] = s.q[0]
        data.qvel[dadr] = s.qd[0]
        n = len(s.q)
        q, qd, tau = np.empty_like(s.q), np.empty_like(s.qd), np.empty_like(s.tau)
        q[0], qd[0], tau[0] = s.q[0], s.qd[0], s.tau[0]
        for j in range(n - 1):
            data.ctrl[act] = s.q_cmd[max(j + 1 - lag, 0)]
            mujoco.mj_step(model, data)
            q[j + 1], qd[j + 1], tau[j + 1] = data.qpos[qadr], data.qvel[dadr], data.actuator_force[act]
        out.append(replace(s, q=q, qd=qd, tau=tau))
    return out


def _model(cell, values: dict) -> mujoco.MjModel:
    """A copy of ``cell``'s model with ``values`` put in (terms that cannot be negative clipped at zero)."""
    from cellguard.calibrate.identify import floating_base
    from cellguard.calibrate.stand import HOLD_DAMPING, HOLD_INERTIA

    m = copy.deepcopy(cell.model)
    for i in hinge_joints(cell):
        name, dof, a = cell.profile.joint_names[i], cell.drives.dadr[i], cell.drives.act[i]
        for parameter, field in (("armature", m.dof_armature), ("damping", m.dof_damping),
                                 ("friction", m.dof_frictionloss)):
            if (parameter, name) in values:
                field[dof] = max(values[(parameter, name)], 0.0)
        kp = values[("kp", name)]
        m.actuator_gainprm[a, 0], m.actuator_biasprm[a, 1] = kp, -kp
    if ("payload", None) in values:
        m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")] += values[("payload", None)]
    if floating_base(cell):
        for j in range(m.njnt):
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                dof = m.jnt_dofadr[j]
                m.dof_armature[dof:dof + 6] = HOLD_INERTIA
                m.dof_damping[dof:dof + 6] = HOLD_DAMPING
        m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return m
