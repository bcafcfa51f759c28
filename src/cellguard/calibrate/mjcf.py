"""A calibrated MJCF: the cell's commissioned model with the identified joint terms and payload put in.

Each hinge joint's ``armature`` [kg*m^2], ``damping`` [N*m*s/rad] and ``frictionloss`` (dry friction)
[N*m] become the identified values (``JointTerms``); an identified payload [kg] becomes a point mass
(a child body ``calibrated_payload`` of ``tool`` at the tool's centre of mass, its mass on a
1 mm sphere that collides with nothing), as ``identify`` models
it. The text is compiled before it is returned, so a file written from it loads. The profile keeps no
payload entry (a measured entry belongs to a joint): the MJCF is where a calibration's payload is
stored, and ``calibrated_payload`` reads it back for a re-fit that holds it.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.torque_model import JointTerms, hinge_joints

PAYLOAD_BODY = "calibrated_payload"
POINT_RADIUS = 1e-3  # the payload's sphere: small enough to be a point mass [m]


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
    return spec.to_xml()


def calibrated_payload(path: Path, profile, option: str = "--profile") -> float:
    """The payload [kg] the calibration of ``profile`` (read from ``path``, given as ``option``) put into its
    calibrated MJCF, beside the profile (a link's target); 0 without a calibration or a payload body. A
    calibration whose MJCF is missing or does not load is refused: holding the payload at zero instead
    biased every term a re-fit estimated (elbow armature 20 % high with 0.2 kg at the tool)."""
    if profile.calibration is None:
        return 0.0
    mjcf = Path(path).resolve().with_name(profile.calibration.mjcf)
    refused = f"{option}: {path}'s calibration {profile.calibration.version} names the MJCF {mjcf}, which"
    if not mjcf.is_file():  # a FIFO would block the reader
        raise CalibrationError(f"{refused} is not a file there; its payload is read from it")
    try:
        model = mujoco.MjModel.from_xml_path(str(mjcf))
    except ValueError as exc:
        first = (str(exc).strip().splitlines() or [exc.__class__.__name__])[0]
        raise CalibrationError(f"{refused} does not load ({first}); its payload is read from it") from None
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY)
    return float(model.body_mass[body]) if body >= 0 else 0.0
