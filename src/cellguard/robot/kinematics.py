"""Damped least-squares inverse kinematics on a MuJoCo model, for teaching poses.

This is the teach pendant of the simulated cells: it turns a Cartesian tool target into
joint positions once, off the servo path. Policies that need IK at run time use the ActionMap.
"""

from __future__ import annotations

import mujoco
import numpy as np


def solve_tool_down(
    model: mujoco.MjModel,
    site: str,
    joints: list[str],
    target: np.ndarray,
    q0: np.ndarray,
    iterations: int = 200,
    damping: float = 1e-3,
) -> np.ndarray:
    """Joint positions of ``joints`` that put ``site`` at ``target`` [m] with its z axis pointing down.

    Starts from ``q0`` (shape (len(joints),)); returns the best solution found. Raises
    ValueError when the residual stays above 0.1 mm (unreachable target).
    """
    data = mujoco.MjData(model)
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
    jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in joints]
    qadr = [model.jnt_qposadr[j] for j in jids]
    dadr = [model.jnt_dofadr[j] for j in jids]
    q = np.array(q0, dtype=np.float64)
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    down = np.array([0.0, 0.0, -1.0])
    err = np.inf
    for _ in range(iterations):
        data.qpos[qadr] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        z_axis = data.site_xmat[sid].reshape(3, 3)[:, 2]
        e = np.concatenate([target - data.site_xpos[sid], np.cross(z_axis, down)])
        err = float(np.linalg.norm(e))
        if err < 1e-7:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, sid)
        jac = np.vstack([jacp[:, dadr], jacr[:, dadr]])
        q = q + jac.T @ np.linalg.solve(jac @ jac.T + damping * np.eye(6), e)
        for i, j in enumerate(jids):
            lo, hi = model.jnt_range[j]
            q[i] = np.clip(q[i], lo, hi)
    if err > 1e-4:
        raise ValueError(f"IK for site {site!r} to {target.round(4).tolist()} left a residual of {err:.2e}")
    return q
