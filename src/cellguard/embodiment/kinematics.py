"""Kinematics: the tool point of a robot from its MJCF, for the layers that must not touch a cell.

The guard (workspace box, tool-speed cap) and the policies need forward kinematics of the
*nominal* robot, the one described by its MJCF file; a simulated cell's live model may carry
injected faults (a slipped tool) and is the cell's own. This object owns a private copy of the
model and data, so it never disturbs a running simulation, and one data per thread: the servo
thread (envelope) and the inference worker (preparing a chunk's tool speeds) call it at once.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from cellguard.errors import UnknownNameError


class Kinematics:
    """Forward kinematics of ``site`` over ``joints`` (the profile's joint order) of an MJCF model."""

    def __init__(self, model: mujoco.MjModel, site: str, joints: Sequence[str]):
        sites = [model.site(i).name for i in range(model.nsite)]
        if site not in sites:
            raise UnknownNameError("tool site", site, sites)
        names = [model.joint(i).name for i in range(model.njnt)]
        missing = [j for j in joints if j not in names]
        if missing:
            raise UnknownNameError("joint", missing[0], names)
        self.site, self.joints = site, tuple(joints)
        self._model, self._local = model, threading.local()
        self._site = model.site(site).id
        self._qadr = span([model.jnt_qposadr[model.joint(j).id] for j in joints])

    @classmethod
    def from_mjcf(cls, path: Path | str, site: str, joints: Sequence[str]) -> Kinematics:
        """Kinematics of the robot described by the MJCF file at ``path``."""
        return cls(mujoco.MjModel.from_xml_path(str(path)), site, joints)

    def tool_point(self, q: np.ndarray) -> np.ndarray:
        """The tool point (3,) [m] in the world frame at joint positions ``q`` (len(joints),) [rad or m]."""
        views = getattr(self._local, "views", None)
        if views is None:  # this thread's data, and its arrays fetched once (they stay put for its lifetime)
            data = mujoco.MjData(self._model)
            views = self._local.views = (data, data.qpos, data.site_xpos[self._site])
        data, qpos, point = views
        qpos[self._qadr] = q
        mujoco.mj_kinematics(self._model, data)
        return point.copy()


def span(index) -> slice | np.ndarray:
    """``index`` as a slice when it is a run of consecutive addresses, else an array: a slice reads and
    writes MjData's arrays in place, several times faster than a fancy index, which copies."""
    index = np.asarray(index)
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index
