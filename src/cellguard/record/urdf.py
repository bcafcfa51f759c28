"""The robot description for viewers: a URDF generated from the compiled MuJoCo model, and its transforms.

Foxglove's 3D panel draws a URDF (from a topic or a file) and places each link by the ``/tf``
transforms named after the links. MuJoCo's compiled model already holds every body's pose in its
parent (``body_pos``, ``body_quat``), each joint's axis and each geom's shape, so the URDF is read
off it (a recorded joint's limits are the profile's, those the guard enforced): one link per body,
one joint per body (revolute or prismatic for a recorded joint, fixed otherwise, floating for a
free base), boxes, spheres and cylinders as visuals (a capsule is drawn as its cylinder; meshes
and planes are left out). ``JointFrames`` turns recorded joint positions into the parent-to-child
transforms of the moving joints.

Limits of the approximation: a joint whose anchor is off its body's origin (``jnt_pos``) is drawn
about the body origin, and joints not in the record (a mimic finger, a free part) stay at their
initial pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from cellguard.embodiment.profile import Profile

_J, _G = mujoco.mjtJoint, mujoco.mjtGeom
_HINGE, _SLIDE, _FREE = int(_J.mjJNT_HINGE), int(_J.mjJNT_SLIDE), int(_J.mjJNT_FREE)
_BOX, _SPHERE, _ELLIPSOID = int(_G.mjGEOM_BOX), int(_G.mjGEOM_SPHERE), int(_G.mjGEOM_ELLIPSOID)
_CYLINDER, _CAPSULE = int(_G.mjGEOM_CYLINDER), int(_G.mjGEOM_CAPSULE)


@dataclass(frozen=True)
class MovingJoint:
    name: str
    parent: str  # link (frame) names
    child: str
    origin_xyz: np.ndarray  # (3,) [m] child at q = 0, in the parent frame
    origin_quat: np.ndarray  # (4,) w, x, y, z
    axis: np.ndarray  # (3,) unit, in the child frame
    prismatic: bool


class JointFrames:
    """Parent-to-child transforms of the recorded joints, and the fixed ones, for ``/tf``."""

    def __init__(self, moving: list[tuple[int, MovingJoint]], fixed: list[tuple[str, str, np.ndarray, np.ndarray]]):
        self.moving = moving  # (column in the recorded joint order, joint)
        self.fixed = fixed  # (parent, child, xyz, quat x y z w)
        joints = [j for _, j in moving]
        self._columns = np.array([column for column, _ in moving], dtype=np.intp)
        self._prismatic = np.array([j.prismatic for j in joints], dtype=bool)
        self._xyz = np.array([j.origin_xyz for j in joints]).reshape(-1, 3)
        self._quat = np.array([j.origin_quat for j in joints]).reshape(-1, 4)  # w x y z
        self._axis = np.array([j.axis for j in joints]).reshape(-1, 3)

    def poses(self, q: np.ndarray) -> np.ndarray:
        """(n, moving, 7): translation [m] and rotation x y z w of every moving joint, for each row of ``q`` (n, dof).

        Vectorised over rows and joints: the recorder turns a whole batch of ticks into ``/tf`` at once.
        """
        q = np.asarray(q, dtype=np.float64)
        value = q.reshape(-1, q.shape[-1])[:, self._columns]  # (n, moving)
        out = np.empty((*value.shape, 7))
        w, x, y, z = self._quat.T
        half = 0.5 * value
        c, s = np.cos(half), np.sin(half)
        bx, by, bz = s * self._axis[:, 0], s * self._axis[:, 1], s * self._axis[:, 2]  # origin times (c, s axis)
        out[..., :3] = self._xyz
        out[..., 3] = w * bx + x * c + y * bz - z * by
        out[..., 4] = w * by - x * bz + y * c + z * bx
        out[..., 5] = w * bz + x * by - y * bx + z * c
        out[..., 6] = w * c - x * bx - y * by - z * bz
        slide = self._prismatic
        if slide.any():  # a prismatic joint keeps its origin's rotation and moves along its axis
            out[:, slide, 3:] = self._quat[slide][:, [1, 2, 3, 0]]
            out[:, slide, :3] += _rotate(self._quat[slide], self._axis[slide] * value[:, slide, None])
        return out


def describe(model: mujoco.MjModel, profile: Profile) -> tuple[str, JointFrames]:
    """The URDF text of ``model`` and the frames of the ``profile``'s joints (the recorded ones, in its order).

    A moving joint's URDF limit states the profile's position range, effort [N·m or N] and velocity [rad/s or
    m/s] to the last digit, the limits the guard enforced: the model's range may be wider (a viewer showed limits not
    in force), and a URDF reader (MoveIt, a planner) takes 0 effort or velocity as a joint that cannot move or push.
    """
    column = {name: i for i, name in enumerate(profile.joint_names)}
    limits = {j.name: j for j in profile.joints}
    links, urdf_joints, moving, fixed = [], [], [], []
    for b in range(1, model.nbody):
        link = _name(model, mujoco.mjtObj.mjOBJ_BODY, b)
        parent = _name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.body_parentid[b]))
        links.append(_link(model, b, link))
        xyz, quat = model.body_pos[b].copy(), model.body_quat[b].copy()
        kind, extra = "fixed", ""
        first, count = int(model.body_jntadr[b]), int(model.body_jntnum[b])
        joint = first if count == 1 else -1
        jname = _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint) if joint >= 0 else f"{link}_fixed"
        jtype = int(model.jnt_type[joint]) if joint >= 0 else -1
        if jtype == _FREE:  # a free base: drawn where it started
            kind = "floating"
            fixed.append((parent, link, xyz, np.array([quat[1], quat[2], quat[3], quat[0]])))
        elif jname in column and jtype in (_HINGE, _SLIDE):
            prismatic = jtype == _SLIDE
            kind = "prismatic" if prismatic else "revolute"
            axis = model.jnt_axis[joint] / np.linalg.norm(model.jnt_axis[joint])
            lo, hi = limits[jname].position
            extra = (f'<axis xyz="{_v(axis)}"/><limit lower="{_exact(lo)}" upper="{_exact(hi)}" '
                     f'effort="{_exact(limits[jname].effort)}" velocity="{_exact(limits[jname].velocity)}"/>')
            moving.append((column[jname], MovingJoint(jname, parent, link, xyz, quat, axis, bool(prismatic))))
        else:
            fixed.append((parent, link, xyz, np.array([quat[1], quat[2], quat[3], quat[0]])))
        urdf_joints.append(f'  <joint name={quoteattr(jname)} type="{kind}"><parent link={quoteattr(parent)}/>'
                           f'<child link={quoteattr(link)}/><origin xyz="{_v(xyz)}" rpy="{_v(_rpy(quat))}"/>'
                           f'{extra}</joint>')
    world = _name(model, mujoco.mjtObj.mjOBJ_BODY, 0)
    text = "\n".join([f'<?xml version="1.0"?>\n<robot name={quoteattr(profile.robot)}>',
                      f"  <link name={quoteattr(world)}/>", *links, *urdf_joints, "</robot>"]) + "\n"
    return text, JointFrames(moving, fixed)


def _link(model, b: int, name: str) -> str:
    visuals = []
    for g in np.flatnonzero(model.geom_bodyid == b):
        size, kind = model.geom_size[g], int(model.geom_type[g])
        if kind == _BOX:
            shape = f'<box size="{_v(2 * size)}"/>'
        elif kind in (_SPHERE, _ELLIPSOID):
            shape = f'<sphere radius="{size[0]:.6g}"/>'
        elif kind in (_CYLINDER, _CAPSULE):
            shape = f'<cylinder radius="{size[0]:.6g}" length="{2 * size[1]:.6g}"/>'
        else:
            continue  # planes, meshes, height fields: not drawn
        rgba = model.geom_rgba[g]
        visuals.append(f'<visual><origin xyz="{_v(model.geom_pos[g])}" rpy="{_v(_rpy(model.geom_quat[g]))}"/>'
                       f'<geometry>{shape}</geometry><material name="{name}_{g}"><color rgba="{_v(rgba)}"/>'
                       f'</material></visual>')
    return f"  <link name={quoteattr(name)}>{''.join(visuals)}</link>"


def _name(model, kind, i: int) -> str:
    return mujoco.mj_id2name(model, kind, i) or f"{'body' if kind == mujoco.mjtObj.mjOBJ_BODY else 'joint'}_{i}"


def _v(values) -> str:
    return " ".join(f"{float(x):.6g}" for x in values)


def _exact(value: float) -> str:
    """A limit as the number the guard enforced (the shortest text that reads back as it): 6 digits rounded outward,
    SO-101's ±105° read ±1.8326 rad against the guard's ±1.8325957."""
    return repr(float(value))


def _rpy(quat: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (fixed axes X, Y, Z) of a quaternion w, x, y, z."""
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(quat, dtype=np.float64))
    r = m.reshape(3, 3)
    return (math.atan2(r[2, 1], r[2, 2]), math.asin(max(-1.0, min(1.0, -r[2, 0]))), math.atan2(r[1, 0], r[0, 0]))


def _rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` (..., k, 3) rotated by the unit quaternions ``quat`` (k, 4) (w, x, y, z): v + 2w(u×v) + u×(2u×v).

    The cross products written out: ``np.cross`` costs tens of µs per call on a few rows."""
    w, x, y, z = quat.T
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return np.stack([vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz),
                     vz + w * tz + (x * ty - y * tx)], axis=-1)
