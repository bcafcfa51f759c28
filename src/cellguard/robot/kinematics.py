"""Damped least-squares inverse kinematics on a MuJoCo model, for teaching poses.

This is the teach pendant of the simulated cells: it turns a Cartesian tool target into
joint positions once, off the servo path. Policies that need IK at run time use the ActionMap.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cellguard.embodiment.kinematics import span


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
    qadr = span([model.jnt_qposadr[j] for j in jids])
    dadr = [model.jnt_dofadr[j] for j in jids]
    lo, hi = model.jnt_range[jids].T.copy()
    q = np.array(q0, dtype=np.float64)
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    # Per iteration: the arithmetic of np.cross and np.clip written out (their call overhead dominated).
    e = np.empty(6)
    regulariser = damping * np.eye(6)
    dx, dy, dz = 0.0, 0.0, -1.0  # the tool's z axis should point down
    xpos, xmat = data.site_xpos[sid], data.site_xmat[sid]
    err = np.inf
    for _ in range(iterations):
        data.qpos[qadr] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        zx, zy, zz = xmat[2], xmat[5], xmat[8]  # the site frame's z axis (third column of its rotation)
        np.subtract(target, xpos, out=e[:3])
        e[3], e[4], e[5] = zy * dz - zz * dy, zz * dx - zx * dz, zx * dy - zy * dx  # z_axis x down
        err = float(np.linalg.norm(e))
        if err < 1e-7:
            break
        mujoco.mj_jacSite(model, data, jacp, jacr, sid)
        jac = np.vstack([jacp[:, dadr], jacr[:, dadr]])
        q = q + jac.T @ np.linalg.solve(jac @ jac.T + regulariser, e)
        np.minimum(np.maximum(q, lo, out=q), hi, out=q)
    if err > 1e-4:
        raise ValueError(f"IK for site {site!r} to {target.round(4).tolist()} left a residual of {err:.2e}")
    return q
