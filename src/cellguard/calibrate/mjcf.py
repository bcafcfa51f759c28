"""A calibrated MJCF: the cell's commissioned model with the identified joint terms and payload put in.

Each hinge joint's ``armature`` [kg*m^2], ``damping`` [N*m*s/rad] and ``frictionloss`` (dry friction)
[N*m] become the identified values (``JointTerms``); an identified payload [kg] becomes a point mass
(a child body ``calibrated_payload`` of ``tool`` at the tool's centre of mass, its mass on a
1 mm sphere that collides with nothing), as ``identify`` models
it. The text is compiled before it is returned, so a file written from it loads. The profile keeps no
payload entry (a measured entry belongs to a joint): the MJCF is where a calibration's payload is
stored, and ``calibrated_payload`` reads it back for a re-fit that holds it. Both ends check what a
calibration puts in against the ranges a real arm could have (``refuse_implausible``): the file sits
beside the profile and is edited by hand (a 1e30 kg payload was held by a re-fit that then wrote
friction 8e70 N*m; a NaN one was read as 4 mg, a 0 kg one as none, each written on as a new calibration).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import mujoco
import numpy as np

from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.torque_model import JointTerms, hinge_joints
from cellguard.embodiment.profile import MEASURED_MAX

PAYLOAD_BODY = "calibrated_payload"
POINT_RADIUS = 1e-3  # the payload's sphere: small enough to be a point mass [m]
# the plausible range of a calibrated payload, generous: at most PAYLOAD_PER_KG times the mass the robot's joints move
# (a serial arm's rated payload is 0.1 to 0.5 of its own mass, a lightweight design's about 1: DLR's LWR III carries its
# own 14 kg), and never above PAYLOAD_KG, as the largest rated payload of a serial arm built is 2300 kg (FANUC
# M-2000iA/2300). A fixed range let 1000 kg through on the 1.94 kg arm. Its inertia about its centre at most that mass
# spread PAYLOAD_RADIUS around it. A payload body is written only for a fitted mass above zero, so 0 kg (or a mass
# MuJoCo took from a density instead) is none identify wrote.
PAYLOAD_PER_KG = 10.0
PAYLOAD_KG = 2500.0
PAYLOAD_RADIUS = 2.0  # [m]


def calibrated_mjcf(cell, terms: JointTerms) -> str:
    """MJCF text of ``cell``'s commissioned model with ``terms`` in; the cell must offer ``mjcf_spec()``."""
    make_spec = getattr(cell, "mjcf_spec", None)
    if make_spec is None:
        raise CalibrationError(f"--write: the {cell.name} cell offers no MJCF to calibrate (no mjcf_spec)")
    spec = make_spec()
    names = [cell.profile.joint_names[i] for i in hinge_joints(cell)]
    for k, name in enumerate(names):
        joint = spec.joint(name)
        joint.armature = float(terms.armature[k])
        damping = np.array(joint.damping, dtype=np.float64, ndmin=1)  # MuJoCo 4: [linear, higher orders]
        damping[0] = terms.damping[k]
        joint.damping = damping if np.ndim(joint.damping) else float(damping[0])
        joint.frictionloss = float(terms.friction[k])
    if terms.payload_kg:
        tool = mujoco.mj_name2id(cell.model, mujoco.mjtObj.mjOBJ_BODY, "tool")
        body = spec.body("tool").add_body(name=PAYLOAD_BODY, pos=cell.model.body_ipos[tool].tolist())
        # a small sphere that touches nothing carries the mass (an explicit inertial is lost by to_xml)
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[POINT_RADIUS, 0, 0], mass=float(terms.payload_kg),
                      contype=0, conaffinity=0, group=3)
    try:
        spec.compile()  # refuses what would not load
    except ValueError as exc:
        raise CalibrationError(f"--write: the calibrated MJCF of {cell.name} would not load: {exc}") from None
    # none a read refuses
    refuse_implausible(spec, cell.profile, cell.model, f"--write: the calibrated MJCF of {cell.name}")
    return spec.to_xml()


def refuse_implausible(spec: mujoco.MjSpec, profile, model: mujoco.MjModel, where: str) -> None:
    """CalibrationError naming the first term of a calibrated MJCF (``spec``, named ``where``) of ``profile``'s robot
    (``model`` its commissioned model) outside the range a real arm could have: per hinge joint of ``profile``,
    armature and damping at least zero and at most what a profile's measured entry may be (``MEASURED_MAX``), dry
    friction at most the joint's effort (more would hold it still); the payload body's mass above zero and at most
    ``payload_max`` of the robot, an inertia written for it at most that mass at ``PAYLOAD_RADIUS``. NaN fails every
    comparison, so it is refused too. Checked on the spec: a file read is checked before it is compiled (compiling a
    1e30 kg payload printed MuJoCo's "inertia matrix is too close to singular")."""
    for joint in profile.joints:
        if joint.kind != "hinge":  # a calibration writes the hinges' terms only
            continue
        terms = spec.joint(joint.name)
        if terms is None:
            raise CalibrationError(f"{where}: has no joint {joint.name}, a joint of the profile; check the file "
                                   "(was it edited?)")
        damping = np.array(terms.damping, dtype=np.float64, ndmin=1)[0]  # MuJoCo 4: [linear, higher orders]
        _within(where, f"joint {joint.name} armature", terms.armature, MEASURED_MAX["armature"], "kg*m^2")
        _within(where, f"joint {joint.name} damping", damping, MEASURED_MAX["damping"], "N*m*s/rad")
        _within(where, f"joint {joint.name} frictionloss", terms.frictionloss, joint.effort, "N*m")
    body = spec.body(PAYLOAD_BODY)
    if body is None:
        return
    high, why = payload_max(model, profile)
    if body.explicitinertial:  # an <inertial> edited in: MuJoCo takes it over the geoms
        _within(where, f"body {PAYLOAD_BODY} inertial mass", body.mass, high, "kg", above_zero=True, why=why)
        for i, moment in enumerate(body.inertia):
            _within(where, f"body {PAYLOAD_BODY} inertial diaginertia[{i}]", moment, high * PAYLOAD_RADIUS ** 2,
                    "kg*m^2", why=f"{high:g} kg at {PAYLOAD_RADIUS:g} m")
    else:  # a geom without a mass (NaN in the spec) would weigh its volume at the default density
        _within(where, f"body {PAYLOAD_BODY} geom mass", sum(g.mass for g in body.geoms), high, "kg",
                above_zero=True, why=why)


def payload_max(model: mujoco.MjModel, profile) -> tuple[float, str]:
    """The heaviest plausible payload [kg] of ``profile``'s robot, and why in words: ``PAYLOAD_PER_KG`` times the mass
    of the bodies its joints move in ``model``, its commissioned model (links, tool, fingers; not a base, a part or a
    payload body), at most ``PAYLOAD_KG``."""
    movers = {int(model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)])
              for name in profile.joint_names}
    payload = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY)
    moved, carried = [False] * model.nbody, [False] * model.nbody  # MuJoCo numbers a body after its parent
    for body in range(1, model.nbody):
        parent = int(model.body_parentid[body])
        moved[body] = body in movers or moved[parent]
        carried[body] = body == payload or carried[parent]
    own = float(sum(model.body_mass[b] for b in range(model.nbody) if moved[b] and not carried[b]))
    own = float(f"{own:.3g}")  # the bound as its message states it
    high = min(PAYLOAD_PER_KG * own, PAYLOAD_KG)
    return high, (f"{PAYLOAD_PER_KG:g} times the {own:.3g} kg that {profile.robot}'s joints move, never above "
                  f"{PAYLOAD_KG:g} kg")


def _within(where: str, field: str, value: float, high: float, unit: str, above_zero: bool = False,
            why: str = "") -> None:
    """CalibrationError naming ``field`` unless ``value`` lies in 0..``high`` (``above_zero``: excluding 0); ``why``
    says where ``high`` comes from."""
    if not (0.0 < value if above_zero else 0.0 <= value) or not value <= high:
        span = f"{'(' if above_zero else '['}0, {high:g}] {unit}" + (f" ({why})" if why else "")
        raise CalibrationError(f"{where}: {field} {float(value):g} {unit} is outside the plausible {span}; no real "
                               "arm has it: check the file (was it edited?)")


def _refuse_not_a_number(path: Path, where: str) -> None:
    """CalibrationError naming the first attribute of the MJCF at ``path`` that holds a NaN: MuJoCo loads it with a
    warning, and a NaN mass as no mass (the payload's 1 mm sphere then weighed 4 mg by the default density)."""
    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return  # MuJoCo's loader names what is wrong
    parents = {child: parent for parent in root.iter() for child in parent}
    for element in root.iter():
        for attribute, text in element.attrib.items():
            if any(_is_nan(token) for token in text.split()):
                name, owner = element.get("name"), parents.get(element)  # an unnamed geom: named by its body
                shown = (f"{element.tag} {name}" if name else f"{element.tag} of {owner.tag} {owner.get('name')}"
                         if owner is not None else element.tag)
                raise CalibrationError(f"{where}: {shown} {attribute} {text!r} is not a number; check the file "
                                       "(was it edited?)")


def _is_nan(token: str) -> bool:
    try:
        return math.isnan(float(token))
    except ValueError:
        return False


def calibrated_payload(path: Path, profile, model: mujoco.MjModel, option: str = "--profile") -> float:
    """The payload [kg] the calibration of ``profile`` (read from ``path``, given as ``option``; ``model`` its robot's
    commissioned model) put into its calibrated MJCF, beside the profile (a link's target); 0 without a calibration or
    a payload body. A calibration whose MJCF is missing, does not load or holds a term no arm has
    (``refuse_implausible``) is refused:
    holding the payload at zero instead biased every term a re-fit estimated (elbow armature 20 % high with 0.2 kg
    at the tool)."""
    if profile.calibration is None:
        return 0.0
    mjcf = Path(path).resolve().with_name(profile.calibration.mjcf)
    refused = f"{option}: {path}'s calibration {profile.calibration.version} names the MJCF {mjcf}, which"
    if not mjcf.is_file():  # a FIFO would block the reader
        raise CalibrationError(f"{refused} is not a file there; its payload is read from it")
    where = f"{option}: {mjcf} ({path}'s calibrated MJCF)"
    _refuse_not_a_number(mjcf, where)
    try:
        spec = mujoco.MjSpec.from_file(str(mjcf))
    except ValueError as exc:
        raise _unloadable(refused, exc) from None
    refuse_implausible(spec, profile, model, where)
    try:
        model = spec.compile()
    except ValueError as exc:
        raise _unloadable(refused, exc) from None
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY)
    return float(model.body_mass[body]) if body >= 0 else 0.0


def _unloadable(refused: str, exc: ValueError) -> CalibrationError:
    first = (str(exc).strip().splitlines() or [exc.__class__.__name__])[0]
    return CalibrationError(f"{refused} does not load ({first}); its payload is read from it")
