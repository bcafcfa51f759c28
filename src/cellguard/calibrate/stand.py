"""A legged robot held on a test stand, for excitation: the body fixed, the feet in the air.

A walking robot's joint torques depend on its body's motion and the foot forces, which its record
does not carry; on a stand both are known (the body is still, the feet touch nothing), so the
joints can be identified as a fixed-base arm is. On hardware the technician mounts the robot; on a
simulated cell ``Stand.apply`` does: it lifts the floating base by ``lift_m`` and holds its six
degrees of freedom with an inertia and damping so large that the legs' reactions cannot move it.
The record's context says ``"mount": "stand"``, which ``identify`` reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

from cellguard.calibrate.identify import CalibrationError

HOLD_INERTIA = 1e6  # added to each base degree of freedom [kg or kg*m^2]
HOLD_DAMPING = 1e8  # on each base degree of freedom [N*s/m or N*m*s/rad]


@dataclass(frozen=True)
class Stand:
    lift_m: float = 0.4  # how far the body is raised above where it stands [m]

    def apply(self, cell) -> None:
        """Mount ``cell`` (a simulated cell with one free joint) on the stand, in place, once after it is built."""
        m, d = cell.model, cell.data
        free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
                and m.body_rootid[m.jnt_bodyid[j]] == m.body_rootid[m.jnt_bodyid[_first_profiled(cell)]]]
        if not free:
            raise CalibrationError(f"--stand: {cell.name} has no floating base to hold; run excite without --stand")
        dof, qadr = m.jnt_dofadr[free[0]], m.jnt_qposadr[free[0]]
        m.dof_armature[dof:dof + 6] = HOLD_INERTIA
        m.dof_damping[dof:dof + 6] = HOLD_DAMPING
        d.qpos[qadr + 2] += self.lift_m
        d.qvel[dof:dof + 6] = 0.0
        mujoco.mj_forward(m, d)
        context = cell.context
        cell.context = lambda: {**context(), "mount": "stand"}


def _first_profiled(cell) -> int:
    return mujoco.mj_name2id(cell.model, mujoco.mjtObj.mjOBJ_JOINT, cell.profile.joint_names[0])
