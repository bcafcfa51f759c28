"""The robot description for viewers: a URDF generated from the compiled MuJoCo model, and its transforms.

Foxglove's 3D panel draws a URDF (from a topic or a file) and places each link by the ``/tf``
transforms named after the links. MuJoCo's compiled model already holds every body's pose in its
parent (``body_pos``, ``body_quat``), each joint's axis and range and each geom's shape, so the URDF
is read off it: one link per body, one joint per body (revolute or prismatic for a recorded joint,
fixed otherwise, floating for a free base), boxes, spheres and cylinders as visuals (a capsule is
drawn as its cylinder; meshes and planes are left out). ``JointFrames`` turns recorded joint
positions into the parent-to-child transforms of the moving joints.

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

    def transforms(self, q: np.ndarray) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
        """(parent, child, translation (3,) [m], rotation x y z w) of every moving joint at positions ``q`` (dof,)."""
        out = []
        for column, j in self.moving:
            value = float(q[column])
            if j.prismatic:
                xyz = j.origin_xyz + _rotate(j.origin_quat, j.axis * value)
                quat = j.origin_quat
            else:
                half = 0.5 * value
                quat = _multiply(j.origin_quat, np.array([math.cos(half), *(math.sin(half) * j.axis)]))
                xyz = j.origin_xyz
            out.append((j.parent, j.child, xyz, np.array([quat[1], quat[2], quat[3], quat[0]])))
        return out


def describe(model: mujoco.MjModel, joints: tuple[str, ...], robot: str) -> tuple[str, JointFrames]:
    """The URDF text of ``model`` and the frames of its recorded ``joints`` (names as in the record)."""
    column = {name: i for i, name in enumerate(joints)}
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
            lo, hi = model.jnt_range[joint] if model.jnt_limited[joint] else (-math.pi, math.pi)
            extra = (f'<axis xyz="{_v(axis)}"/><limit lower="{lo:.6g}" upper="{hi:.6g}" effort="0" velocity="0"/>')
            moving.append((column[jname], MovingJoint(jname, parent, link, xyz, quat, axis, bool(prismatic))))
        else:
            fixed.append((parent, link, xyz, np.array([quat[1], quat[2], quat[3], quat[0]])))
        urdf_joints.append(f'  <joint name={quoteattr(jname)} type="{kind}"><parent link={quoteattr(parent)}/>'
                           f'<child link={quoteattr(link)}/><origin xyz="{_v(xyz)}" rpy="{_v(_rpy(quat))}"/>'
                           f'{extra}</joint>')
    world = _name(model, mujoco.mjtObj.mjOBJ_BODY, 0)
    text = "\n".join([f'<?xml version="1.0"?>\n<robot name={quoteattr(robot)}>', f"  <link name={quoteattr(world)}/>",
                      *links, *urdf_joints, "</robot>"]) + "\n"
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


def _rpy(quat: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (fixed axes X, Y, Z) of a quaternion w, x, y, z."""
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(quat, dtype=np.float64))
    r = m.reshape(3, 3)
    return (math.atan2(r[2, 1], r[2, 2]), math.asin(max(-1.0, min(1.0, -r[2, 0]))), math.atan2(r[1, 0], r[0, 0]))


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return out


def _rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    mujoco.mju_rotVecQuat(out, np.asarray(v, dtype=np.float64), np.asarray(quat, dtype=np.float64))
    return out
