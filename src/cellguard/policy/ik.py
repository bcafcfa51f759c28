"""Differential IK with mink for end-effector actions: a target pose per chunk step -> joint targets.

Runs off the servo path, once per chunk: each step starts from the previous step's solution, so a chunk of H
poses costs H short solves. Joints outside ``IkSpec.joints`` (the gripper, a free part) are frozen; the guard's
soft limits bound the solution, at the run's ``guard.soft_margin`` (bounded by the model's wider ranges, or by the
default margin under a scenario's wider one, a target past them was "reached" and the guard held the joint at its
soft limit: the tool missed, no failure named). A step the site does not reach within ``REACH_TOLERANCE`` refuses
the whole chunk: the solver's best effort for an unreachable target flipped between two joint solutions step after
step and moved the tool away from it. The solver is local (it follows on
from the current pose, so a chunk stays continuous): a miss says the target was not reached from there, not that
no joint pose reaches it (one far behind the base can need the base turned further than a local solve finds;
re-seeding it would give a jump the guard refuses anyway).
"""

from __future__ import annotations

import mujoco
import numpy as np

from cellguard.embodiment import Profile
from cellguard.embodiment.profile import SOFT_MARGIN
from cellguard.errors import ConfigError
from cellguard.embodiment.action_map import EE_AXES, IkSpec
from cellguard.policy.adapter import InferenceError

POSITION_TOLERANCE = 1e-4  # [m] a step's solve stops when the site is this close to its target
REACH_TOLERANCE = 1e-3  # [m] a step whose site ends further than this from its target was not reached
MAX_ITERATIONS = 30  # per chunk step
LIMIT_REACHED = 1e-3  # [rad or m] an IK joint this close to a soft limit is named as held there by a refusal


def _mink():
    try:
        import mink
    except ImportError:  # pragma: no cover - depends on the environment
        raise ConfigError("action map: end-effector actions need mink; install it with "
                          "pip install 'cellguard[ik]'") from None
    return mink


class IkSolver:
    """Solves site poses (H, 6: x y z [m], roll pitch yaw [rad]) into joints ``spec.joints``, inside the soft limits
    ``soft_margin`` (the guard's, a fraction of each joint's range) inside the profile's."""

    def __init__(self, model: mujoco.MjModel, profile: Profile, spec: IkSpec, soft_margin: float = SOFT_MARGIN):
        mink = self._mink = _mink()
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, spec.site) < 0:
            sites = [model.site(i).name for i in range(model.nsite)]
            raise ConfigError(f"action map: ik.site: {spec.site!r} is not a site of the model; sites: {', '.join(sites)}")
        self.model, self.spec = model, spec
        self._mapped = np.array([axis in spec.axes for axis in EE_AXES])
        self.joint_index = np.array([profile.index(j) for j in spec.joints])
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in profile.joint_names]
        self._qadr = np.array([model.jnt_qposadr[j] for j in jids])
        moved = {int(model.jnt_dofadr[jids[i]]) for i in self.joint_index}
        self._frozen = [d for d in range(model.nv) if d not in moved]
        limited = [j for j in range(model.njnt) if model.jnt_limited[j] and model.jnt_type[j] in (2, 3)]
        self._limited_qadr = np.array([model.jnt_qposadr[j] for j in limited], dtype=int)
        self._range = model.jnt_range[limited].T.copy()  # (2, n): a frozen joint outside its range makes the QP infeasible
        self._configuration = mink.Configuration(model)
        # Without yaw among the actions, only the tool axis direction is held: spin about it is free.
        cost = spec.orientation_cost * (np.ones(3) if spec.full_orientation else np.array([1.0, 1.0, 0.0]))
        self._task = mink.FrameTask(spec.site, "site", position_cost=1.0, orientation_cost=cost)
        self._posture = mink.PostureTask(model, cost=1e-3)
        lo, hi = (limit[self.joint_index] for limit in profile.soft_limits(soft_margin))  # where the guard brakes
        self._box = _JointBox(mink, model.nv, [int(model.jnt_dofadr[jids[i]]) for i in self.joint_index],
                              self._qadr[self.joint_index], lo, hi)
        self._limits = [self._box]
        self._units = ["rad" if profile.joints[i].kind == "hinge" else "m" for i in self.joint_index]
        self._constraints = [mink.DofFreezingTask(model, dof_indices=self._frozen)] if self._frozen else []

    def pose(self, q: np.ndarray) -> np.ndarray:
        """The site pose (6,) at joint state ``q`` (dof,), profile order."""
        self._set(q)
        return self._pose_now()

    def solve(self, targets: np.ndarray, q_now: np.ndarray, delta: bool) -> np.ndarray:
        """Joint targets (H, len(spec.joints)) for pose targets (H, 6); axes outside ``spec.axes`` keep the pose
        at ``q_now``. A step whose set axes are not finite gives NaN joints, so the guard refuses the chunk
        (never a silent hold). With ``delta`` the targets are offsets from the pose at ``q_now``. A step
        whose position the site cannot reach within REACH_TOLERANCE raises InferenceError naming it; the
        orientation is a weighted compromise (``orientation_cost``), not checked.
        """
        mink = self._mink
        self._set(q_now)
        start = self._pose_now()
        self._posture.set_target(self._configuration.q.copy())
        goal = np.where(self._mapped, targets, 0.0 if delta else start)
        if delta:
            goal = goal + start
        out = np.empty((goal.shape[0], len(self.joint_index)))
        tasks = [self._task, self._posture]
        for h, pose in enumerate(goal):
            if not np.isfinite(pose).all():
                out[h] = np.nan
                continue
            rotation = mink.SO3.from_rpy_radians(pose[3], pose[4], pose[5])
            self._task.set_target(mink.SE3.from_rotation_and_translation(rotation, pose[:3]))
            for _ in range(MAX_ITERATIONS):
                error = self._task.compute_error(self._configuration)
                if np.linalg.norm(error[:3]) < POSITION_TOLERANCE:
                    break
                velocity = mink.solve_ik(self._configuration, tasks, 1.0, "daqp", damping=1e-3,
                                         limits=self._limits, constraints=self._constraints)
                self._configuration.integrate_inplace(velocity, 1.0)
            self._check_reached(h, pose[:3])
            out[h] = self._configuration.q[self._qadr[self.joint_index]]
        return out

    def _check_reached(self, step: int, target: np.ndarray) -> None:
        miss = np.linalg.norm(self._pose_now()[:3] - target)
        if miss > REACH_TOLERANCE:
            where = ", ".join(f"{v * 1e3:.1f}" for v in target)
            raise InferenceError(f"IK: step {step}: target ({where}) mm for site {self.spec.site!r} not reached "
                                 f"from the current pose: the solve ends {miss * 1e3:.1f} mm away (tolerance "
                                 f"{REACH_TOLERANCE * 1e3:g} mm; out of reach, or only reached from another joint "
                                 f"configuration){self._held()}; chunk refused")

    def _held(self) -> str:
        """The IK joints the solve left at a soft limit, as a clause: the target may lie past one."""
        box, q = self._box, self._configuration.q[self._box.qadr]
        held = [f"{self.spec.joints[i]} at {bound:.3f} {unit}"
                for i, (v, lo, hi, unit) in enumerate(zip(q, box.lower, box.upper, self._units))
                for bound in (lo, hi) if abs(v - bound) < LIMIT_REACHED]
        return f"; held at the guard's soft limit: {', '.join(held)}" if held else ""

    def _set(self, q: np.ndarray) -> None:
        full = self._configuration.q.copy()
        full[self._qadr] = q
        full[self._limited_qadr] = np.clip(full[self._limited_qadr], *self._range)
        self._configuration.update(full)

    def _pose_now(self) -> np.ndarray:
        transform = self._configuration.get_transform_frame_to_world(self.spec.site, "site")
        rpy = transform.rotation().as_rpy_radians()
        return np.concatenate([transform.translation(), [rpy.roll, rpy.pitch, rpy.yaw]])


class _JointBox:
    """A mink limit: the IK joints (hinges and slides, one dof each) inside [lower, upper], approached at ``gain``
    of the distance left per step as mink's own ConfigurationLimit does (which reads only the model's ranges)."""

    def __init__(self, mink, nv: int, dofs: list[int], qadr: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 gain: float = 0.95):
        rows = np.zeros((len(dofs), nv))
        rows[np.arange(len(dofs)), dofs] = 1.0
        self._G, self._constraint = np.vstack([rows, -rows]), mink.Constraint
        self.qadr, self.lower, self.upper, self._gain = qadr, lower, upper, gain

    def compute_qp_inequalities(self, configuration, dt: float):
        q = configuration.q[self.qadr]
        return self._constraint(G=self._G, h=self._gain * np.concatenate([self.upper - q, q - self.lower]))
