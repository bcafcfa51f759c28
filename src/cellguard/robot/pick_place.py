"""The pick-place task both arm cells share: pick a part from a fixture, place it in the drop zone, go home.

The camera is a ceiling sensor that reports the part and the fixture fiducial in its own frame;
the policy maps that to the world with the *calibrated* extrinsic, so a knocked camera is a
different fault from a moved fixture. The gripper captures a part whose centre lies within
``Layout.capture_radius`` of the tool point when the fingers close; the part is then held by a
weld constraint until the fingers open.

A cell model provides, by name: bodies ``part`` (free joint ``part``), ``tool`` (rigid on the
last wrist link, carrying site ``tcp``), mocap bodies ``fixture`` and ``camera_mount``; sites
``fixture_datum`` and ``drop_zone``; a weld equality ``grasp`` (tool to part, inactive); one
position actuator per profiled joint, named as the joint; the profile lists its joints in the model's order, the
gripper last (checked, with the home pose against the profile's limits and the layout's workspace box, when the cell
is built: ``_misfit``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import mujoco
import numpy as np

from cellguard.embodiment import Kinematics, Profile
from cellguard.embodiment.kinematics import span
from cellguard.errors import ProfileError
from cellguard.robot.drives import DrivenCell, PositionDrives
from cellguard.robot.faults import FAULTS
from cellguard.robot.kinematics import solve_tool_down
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.state import Observation

# Camera frame: x along world x, z looking down.
CAMERA_ROTATION = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class Layout:
    """What differs between pick-place cells: part size, gripper thresholds, home pose, noise, box.

    Gripper values are in the gripper joint's own unit: [m] of finger opening for a slide
    gripper, [rad] of jaw angle for a hinge gripper; larger is more open.
    """

    part_half: float  # [m] half edge of the cube part
    capture_radius: float  # [m] horizontal offset the finger pads still centre
    capture_height: float  # [m] vertical offset the pads still grip
    drop_tolerance: float  # [m] a placed part must rest this close to the drop zone centre
    gripper_closed: float  # opening below which the pads touch a centred part
    gripper_released: float  # opening above which a held part is let go
    q_home: tuple[float, ...]  # (dof,) profile order, which is the model's
    workspace_box: tuple[tuple[float, float, float], tuple[float, float, float]]  # tool-point box [m]
    camera_noise: float = 1e-4  # [m] 1-sigma noise of each camera coordinate
    current_noise: float = 0.01  # [A] 1-sigma noise of each motor current reading
    brake_damping: float = 200.0  # [N·m·s/rad] joint damping while the brakes hold (power removed)
    approach: float = 0.06  # [m] height above a pick or place a recovery comes down from
    ik_joints: tuple[str, ...] = ()  # joints a recovery's IK moves (the rest stay as at home); () = all but the gripper


def _misfit(model: mujoco.MjModel, profile: Profile, layout: Layout) -> str | None:
    """Why ``profile`` does not fit the cell's model and ``layout``, or None. Unchecked, a joint missing or extra was
    a numpy traceback, reordered joints took each other's home values (every chunk refused), and a home pose outside
    the profile's position limits ran, its retreats to home braked at the limit; one whose tool point lay outside the
    workspace box stopped the run at its first chunk, as if the policy were lost."""
    names = profile.joint_names
    if len(layout.q_home) != len(names):
        return (f"{len(names)} joints ({', '.join(names)}) for a home pose of {len(layout.q_home)} (q_home: one value "
                f"per joint, in profile order, the gripper last)")
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "tool")
    if body < 0:
        return "its model has no body 'tool'"
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tcp") < 0:
        return "its model has no site 'tcp' (the tool point)"
    carry = set()  # the tool body and the bodies that carry it: a joint of one of them moves the tool point
    while body > 0:
        carry.add(body)
        body = int(model.body_parentid[body])
    joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    moves = [int(model.jnt_bodyid[j]) in carry for j in joints]
    if moves[-1]:
        return f"its last joint {names[-1]!r} moves the tool; the gripper must be the last joint"
    if not all(moves[:-1]):
        still = names[moves.index(False)]
        return f"its joint {still!r} does not move the tool; only the last one, the gripper, may not"
    # the profile's order is the model's: the same joints listed in another order took each other's home values
    # (shoulder_pan at the elbow's 1.9 rad), and nothing said so
    model_order = [n for _, n in sorted(zip(model.jnt_qposadr[joints].tolist(), names))]
    if list(names) != model_order:
        return (f"its joints ({', '.join(names)}) are not in the model's order ({', '.join(model_order)}); q_home "
                "and every action follow the profile's order: list the joints as the model does")
    stray = [j for j in layout.ik_joints if j not in names[:-1]]
    if stray:
        return f"the layout's ik_joints {stray} are not among its arm joints ({', '.join(names[:-1])})"
    j = profile.first_outside(layout.q_home)
    if j is not None:
        joint, q = profile.joints[j], layout.q_home[j]
        (lo, hi), unit = joint.position, "rad" if joint.kind == "hinge" else "m"
        return f"the home pose puts {joint.name} at {q:g} {unit}, outside its position limits [{lo:g}, {hi:g}] {unit}"
    tip = Kinematics(model, "tcp", names).tool_point(np.asarray(layout.q_home, dtype=np.float64))
    low, high = (np.asarray(corner, dtype=np.float64) for corner in layout.workspace_box)
    if not ((low <= tip) & (tip <= high)).all():  # as the guard's box check reads it
        return (f"the home pose puts the tool point at {np.round(tip, 3).tolist()} m, outside the layout's "
                f"workspace_box {[list(map(float, corner)) for corner in layout.workspace_box]} m")
    return None


class PickPlaceCell(DrivenCell):
    """A simulated pick-place cell at the model's servo period; joint order is the profile's."""

    name: str
    # every fault kind found, a new file's too: a fault acts only through the policy channel and the world-change
    # setters (``world_changes.ADDED``, ``MULTIPLIED``), and a pick-place cell has every one of them
    supported_faults = frozenset(FAULTS)
    failure_checks = ("grasp_missed", "place_missed")  # what ``failed_check`` may report

    def __init__(self, model: mujoco.MjModel, profile: Profile, layout: Layout, seed: int = 0):
        misfit = _misfit(model, profile, layout)
        if misfit is not None:
            raise ProfileError(f"profile {profile.robot!r} version {profile.version}: {misfit}")
        self.model, self.profile, self.layout = model, profile, layout
        self.data = mujoco.MjData(model)
        self._taught = copy.deepcopy(model)  # as commissioned: recoveries plan on it, faults never touch it
        self.dt_ns = round(model.opt.timestep * 1e9)
        self.rng = np.random.default_rng(seed)
        m = model
        self.drives = PositionDrives(m, self.data, profile, self.rng, layout.current_noise, layout.brake_damping)
        self._qadr, self._dadr = self.drives.qadr, self.drives.dadr
        # per tick: the arm joints (all but the gripper) and the gripper opening, as plain indices
        self._arm_q, self._arm_v, self._q = span(self._qadr[:-1]), span(self._dadr[:-1]), span(self._qadr)
        self._gripper_q = int(self._qadr[-1])
        self._qpos, self._qvel = self.data.qpos, self.data.qvel  # MjData's arrays stay put: fetched once
        self._part_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "part")
        part_joint = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "part")
        self._part_qadr, self._part_dadr = m.jnt_qposadr[part_joint], m.jnt_dofadr[part_joint]
        self._tool_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tool")
        self._tcp = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tcp")
        self._datum = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "fixture_datum")
        self._drop = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "drop_zone")
        self._grasp_eq = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, "grasp")
        self._fixture_mocap = m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "fixture")]
        self._camera_mocap = m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "camera_mount")]
        # Nominal (commissioned) values that faults perturb; faults set absolute values from these.
        self.nominal = {
            "fixture": self.data.mocap_pos[self._fixture_mocap].copy(),
            "camera": self.data.mocap_pos[self._camera_mocap].copy(),
            "tool": m.body_pos[self._tool_body].copy(),
            "part_mass": float(m.body_mass[self._part_body]),
            "part_inertia": m.body_inertia[self._part_body].copy(),
        }
        self._part_offset = np.zeros(3)  # [m] where this cycle's part is presented, off the datum
        # The camera extrinsic as calibrated at commissioning; the policy side uses this.
        self.camera_calibration = {"position": self.nominal["camera"].tolist(), "rotation": CAMERA_ROTATION.tolist(),
                                   "calibrated": "2026-10-14"}
        self.q_home = np.array(layout.q_home, dtype=np.float64)
        self._arm_home = self.q_home[:-1].copy()
        self.data.qpos[self._qadr] = self.q_home
        self.drives.write(self.q_home)
        mujoco.mj_forward(m, self.data)
        self._cycle_start_ns = 0
        self._left_home = False
        self._attempt: dict | None = None  # tool pose when the fingers first closed this cycle
        self._grasped = False
        self._release_ns: int | None = None
        self._closed = False
        self._seen_at_start: dict = {}
        self.safety_inputs = SafetyInputs()  # the simulated safety controller's outputs; set by scenario or test
        self.tool_site, self.workspace_box = "tcp", layout.workspace_box
        self._fk = Kinematics(m, "tcp", profile.joint_names)  # the live model's (one MjData per thread)
        self._taught_fk = mujoco.MjData(self._taught)
        self._failed: str | None = None
        self.approach_height = layout.approach
        self.gripper_open, self.gripper_shut = float(self.q_home[-1]), 0.5 * layout.gripper_closed

    # -- Robot -------------------------------------------------------------------------
    def tool_point(self, q: np.ndarray) -> np.ndarray:
        """Forward kinematics: the tool point (3,) [m] at joint positions ``q`` (dof,), off the live model state."""
        return self._fk.tool_point(q)

    def step(self) -> None:
        self.physics_step()
        self._update_grasp()

    # -- Task ------------------------------------------------------------------------
    def observe(self) -> Observation:
        return Observation(
            t_ns=self.t_ns,
            q=self.data.qpos[self._qadr].copy(),
            qd=self.data.qvel[self._dadr].copy(),
            measurements={
                "part_in_camera": self._in_camera(self.data.xpos[self._part_body]),
                "fixture_in_camera": self._in_camera(self.data.site_xpos[self._datum]),
            },
        )

    def _in_camera(self, world: np.ndarray) -> np.ndarray:
        """What the camera reports of a world point: its own frame, with noise."""
        rel = CAMERA_ROTATION.T @ (world - self.data.mocap_pos[self._camera_mocap])
        return rel + self.rng.normal(0.0, self.layout.camera_noise, 3)

    def _seen(self, world: np.ndarray) -> list[float]:
        """A camera reading mapped to the world through the commissioning calibration [m]."""
        return (CAMERA_ROTATION @ self._in_camera(world) + self.nominal["camera"]).tolist()

    def begin_cycle(self, cycle: int) -> None:
        self.data.eq_active[self._grasp_eq] = 0
        datum = (self.data.mocap_pos[self._fixture_mocap] + self.model.site_pos[self._datum]
                 + np.array([0.0, 0.0, self.layout.part_half]))
        jitter = self.rng.normal(0.0, 2e-4, 3) * np.array([1.0, 1.0, 0.0])
        self.data.qpos[self._part_qadr:self._part_qadr + 3] = datum + jitter + self._part_offset
        self.data.qpos[self._part_qadr + 3:self._part_qadr + 7] = [1.0, 0.0, 0.0, 0.0]
        self.data.qvel[self._part_dadr:self._part_dadr + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self._cycle_start_ns = self.t_ns
        self._seen_at_start = {"part_seen_m": self._seen(self.data.xpos[self._part_body]),
                               "fixture_seen_m": self._seen(self.data.site_xpos[self._datum])}
        self._left_home = False
        self._attempt = None
        self._grasped = False
        self._release_ns = None
        self._failed = None

    def cycle_finished(self) -> bool:
        """Back home after leaving it, and slow; asked every tick, so on plain floats (numpy's max of six
        values costs more than the list)."""
        away = max(map(abs, (self._qpos[self._arm_q] - self._arm_home).tolist()))
        if not self._left_home:
            self._left_home = away > 0.05
            return False
        return away < 0.01 and max(map(abs, self._qvel[self._arm_v].tolist())) < 0.05

    def cycle_under_way(self) -> bool:
        """The arm has left home this cycle."""
        return self._left_home

    def end_cycle(self) -> dict:
        part = self.data.xpos[self._part_body]
        drop = self.data.site_xpos[self._drop]
        placed = (
            self._grasped
            and self._release_ns is not None
            and float(np.linalg.norm(part[:2] - drop[:2])) < self.layout.drop_tolerance
            and part[2] < self.layout.part_half + 0.003  # resting on the table (z = 0)
        )
        outcome = {
            "success": bool(placed),
            "cycle_time_s": (self.t_ns - self._cycle_start_ns) * 1e-9,
            "grasped": self._grasped,
            "place_error_mm": float(np.linalg.norm(part[:2] - drop[:2]) * 1e3),
            **self._seen_at_start,
        }
        if self._attempt is not None:
            outcome.update(self._attempt)
        if self._release_ns is not None:
            outcome["release_time_s"] = (self._release_ns - self._cycle_start_ns) * 1e-9
        return outcome

    def context(self) -> dict:
        return {
            "cell": self.name,
            "fixture_datum": self.nominal["fixture"].tolist(),
            "camera_calibration": self.camera_calibration,
            "tool_offset": self.nominal["tool"].tolist(),
        }

    def _update_grasp(self) -> None:
        d, layout = self.data, self.layout
        opening = float(d.qpos[self._gripper_q])
        held = bool(d.eq_active[self._grasp_eq])
        if held and opening > layout.gripper_released:
            d.eq_active[self._grasp_eq] = 0
            self._release_ns = self.t_ns
            part, drop = d.xpos[self._part_body], d.site_xpos[self._drop]
            if float(np.linalg.norm(part[:2] - drop[:2])) >= layout.drop_tolerance:
                self._failed = "place_missed"
        closed = opening < layout.gripper_closed
        closing, self._closed = closed and not self._closed, closed
        if closing and not held:
            tcp = self.data.site_xpos[self._tcp]
            offset = self.data.xpos[self._part_body] - tcp
            if np.linalg.norm(offset[:2]) < self.layout.capture_radius and abs(offset[2]) < self.layout.capture_height:
                self._grasped = True
                self._weld_part()
            else:
                self._failed = "grasp_missed"
            if self._attempt is not None:
                return  # the cycle's first grasp is its geometry; a recovery's retries are the recovery's
            self._attempt = {
                "grasp_time_s": (self.t_ns - self._cycle_start_ns) * 1e-9,
                "grasp_tcp_m": tcp.tolist(),
                "grasp_q": self.data.qpos[self._qadr].tolist(),
                "grasp_offset_mm": (offset * 1e3).tolist(),  # part centre minus tool point, world frame
            }

    def _weld_part(self) -> None:
        """Hold the part where it sits in the hand: weld at the current relative pose."""
        m, d = self.model, self.data
        tool_pos, part_pos = d.xpos[self._tool_body], d.xpos[self._part_body]
        tool_quat, part_quat = d.xquat[self._tool_body], d.xquat[self._part_body]
        inv = np.zeros(4)
        mujoco.mju_negQuat(inv, tool_quat)
        rel_pos = np.zeros(3)
        mujoco.mju_rotVecQuat(rel_pos, part_pos - tool_pos, inv)
        rel_quat = np.zeros(4)
        mujoco.mju_mulQuat(rel_quat, inv, part_quat)
        # weld eq_data: anchor(3), relpose pos(3), relpose quat(4), torquescale(1); relpose is body2 in body1
        m.eq_data[self._grasp_eq, 0:3] = 0.0
        m.eq_data[self._grasp_eq, 3:6] = rel_pos
        m.eq_data[self._grasp_eq, 6:10] = rel_quat
        m.eq_data[self._grasp_eq, 10] = 1.0
        d.eq_active[self._grasp_eq] = 1

    # -- Failed checks and what recoveries plan with (the commissioned model, never the faulted one) --------
    def failed_check(self) -> str | None:
        """The check that failed since the last call (``grasp_missed``, ``place_missed``), once; else None."""
        failed, self._failed = self._failed, None
        return failed

    def reach(self, target: np.ndarray, q0: np.ndarray) -> np.ndarray:
        """Arm joints (dof-1,) that put the tool point at ``target`` [m], tool down, on the commissioned model."""
        names = list(self.profile.joint_names[:-1])
        moved = [names.index(j) for j in (self.layout.ik_joints or names)]
        arm = self.q_home[:-1].copy()
        arm[moved] = solve_tool_down(self._taught, "tcp", [names[i] for i in moved],
                                     np.asarray(target, dtype=np.float64), np.asarray(q0)[moved])
        return arm

    def tool_taught(self, arm: np.ndarray) -> np.ndarray:
        """Where the commissioned model puts the tool point (3,) [m] at arm joints ``arm`` (dof-1,)."""
        self._taught_fk.qpos[self._qadr[:-1]] = arm
        mujoco.mj_kinematics(self._taught, self._taught_fk)
        return self._taught_fk.site_xpos[self._tcp].copy()

    def drop_point(self) -> np.ndarray:
        """Tool point (3,) [m] that sets a held part down on the commissioned drop zone."""
        mujoco.mj_kinematics(self._taught, self._taught_fk)
        point = self._taught_fk.site_xpos[self._drop].copy()
        point[2] = self.layout.part_half + 0.002
        return point

    def part_seen(self) -> np.ndarray:
        """The part centre (3,) [m] as the camera sees it now, through the commissioning calibration."""
        return np.asarray(self._seen(self.data.xpos[self._part_body]))

    # -- Faults (absolute settings from the nominal values) --------------------------------
    def set_fixture_offset(self, offset: np.ndarray) -> None:
        self.data.mocap_pos[self._fixture_mocap] = self.nominal["fixture"] + offset

    def set_camera_offset(self, offset: np.ndarray) -> None:
        self.data.mocap_pos[self._camera_mocap] = self.nominal["camera"] + offset

    def set_tool_offset(self, offset: np.ndarray) -> None:
        self.model.body_pos[self._tool_body] = self.nominal["tool"] + offset

    def set_part_offset(self, offset: np.ndarray) -> None:
        """Present the next part ``offset`` [m] off its fixture datum (a mis-seated part)."""
        self._part_offset = np.asarray(offset, dtype=np.float64)

    # -- Process changes --------------------------------------------------------------------
    def payload_problem(self, extra_kg: float) -> str | None:
        """Why the part cannot carry ``extra_kg`` more (it would weigh nothing or less), or None."""
        part = self.nominal["part_mass"]
        if part + extra_kg > 0:
            return None
        return f"the part would weigh {(part + extra_kg) * 1e3:g} g ({part * 1e3:g} g {extra_kg * 1e3:+g} g)"

    def set_payload(self, extra_kg: float) -> None:
        """The part carried weighs ``extra_kg`` more than at commissioning (a new product variant)."""
        mass = self.nominal["part_mass"] + extra_kg
        self.model.body_mass[self._part_body] = mass
        self.model.body_inertia[self._part_body] = self.nominal["part_inertia"] * mass / self.nominal["part_mass"]
