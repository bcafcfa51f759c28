"""LeRobot bridge (``robot: lerobot:TYPE?port=...&id=...``): any registered LeRobot ``Robot`` as a cellguard Robot.

The robot is built by LeRobot itself: its config class from LeRobot's config registry
(``RobotConfig.get_choice_class``, after LeRobot's third-party plugin discovery), the options
parsed by draccus as LeRobot's own command line parses them, the robot from
``make_robot_from_config``. Then ``connect`` once, ``get_observation`` per ``read``,
``send_action`` per ``write``, ``disconnect`` at ``close``.

Units are data, not code: the units map (an ``ActionMap`` file whose action names are the
robot's action keys, e.g. ``shoulder_pan.pos`` in degrees, ``gripper.pos`` 0..100) turns SI
setpoints into LeRobot's units and the robot's readings back. ``write`` returns what
``send_action`` *returned* (what the robot really sent after its own clipping), mapped back to SI,
never the request. Non-finite setpoints never reach ``send_action``: ``write`` refuses them.

Readings: joint positions from the ``<motor>.pos`` keys; velocity by finite difference of two
reads on the monotonic clock; motor current [A] from ``<motor>.current`` keys where the robot
reports them (LeRobot's SO follower does not: current and effort then read 0, and the
diagnosis cannot name friction or servo causes on that robot); any other float keys
``<name>.x/.y/.z`` are measurements the policy sees (``Observation.measurements[name]``); any
other key can be a digital input (``cycle: {source: input, input: KEY}`` ends a cycle on it).

A hung bus must not freeze the tick (and every watchdog with it): the robot's calls run one at a
time on a thread of their own (``RobotCalls``), and one that has not returned within the scenario's
``realtime.read_timeout_s`` is ``robot_read_timeout`` or ``robot_write_failed``; until it returns,
later calls fail at once.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from typing import TYPE_CHECKING

from cellguard.embodiment import Profile, load_profile
from cellguard.errors import CellguardError, ConfigError, ScenarioError
from cellguard.options import bounded_float, split_options
from cellguard.robot.protocol import RobotLinkError, SafetyInputs
from cellguard.robot.state import Observation, State
from cellguard.threads import start_thread

OPTIONS = {"units": "units map YAML (default: the embodiment's LeRobot units map)",
           "embodiment": "profile to guard with (default from the robot type)",
           "hz": "servo rate [Hz] of the loop that drives it (default 50)",
           "lockstep": "1: a simulated robot that moves one period per send_action; the loop keeps its time",
           "home": "home pose, comma-separated in the units map's order and units (the retreat at the end goes "
                   "there; cycle source home needs it); without it the robot stays where the run ends"}
READ_TIMEOUT_S = 0.05  # the scenario's realtime.read_timeout_s default
# A home this close past a limit (a share of the joint's range) is at the limit: a profile's limits are written to a
# few digits (the SO-101 gripper's 0 and 100, its end stops -10 and 100 deg, lie 3e-5 rad past -0.1745 and 1.7453 rad)
HOME_SLACK = 1e-4
_AXES = ("x", "y", "z")

if TYPE_CHECKING:
    from cellguard.embodiment.action_map import ActionMap


class BridgeError(CellguardError):
    """A bridge call that failed at run time: a refused setpoint, a robot that raised."""


@dataclass(frozen=True)
class Embodiment:
    """What cellguard needs to guard a robot type: its profile (checked on a model) and its units map."""

    load_model: Callable[[], object]  # the MuJoCo model the profile is checked against
    profile: Path
    units: Path


def _so101() -> Embodiment:
    from cellguard.robot import so101_cell

    return Embodiment(so101_cell.load_model, so101_cell.ASSETS / "so101_profile.yaml",
                      so101_cell.ASSETS / "so101_lerobot_units.yaml")


EMBODIMENTS: dict[str, Callable[[], Embodiment]] = {"so101": _so101}
# LeRobot robot types and the embodiment they default to; others need ?embodiment=NAME.
TYPE_EMBODIMENT = {"so101_follower": "so101", "cellguard_so101": "so101"}


@dataclass
class _Call:
    what: str
    fn: Callable
    args: tuple
    started_ns: int
    done: threading.Event = field(default_factory=threading.Event)
    result: object = None
    error: BaseException | None = None


class RobotCalls:
    """A robot's calls, one at a time on a daemon thread of their own, each awaited at most ``timeout_s``.

    A call still running when the next is asked is not queued behind it (a bus that hung on a read
    would take the write with it): the next fails at once, naming the call that hangs and for how long.
    """

    def __init__(self, name: str, timeout_s: float):
        self.name, self.timeout_ns = name, round(timeout_s * 1e9)
        self._asked = threading.Condition()
        self._call: _Call | None = None
        refused = start_thread(threading.Thread(target=self._serve, name=f"lerobot {name}", daemon=True))
        if refused is not None:  # before the robot is connected: nothing to undo
            raise BridgeError(f"lerobot {name}: cannot drive the robot: {refused}; not connected")

    def __call__(self, what: str, fn: Callable, *args):
        """``fn(*args)``'s result; its exception as is; ``TimeoutError`` naming the call that hangs."""
        with self._asked:
            if self.hung_for_ns():
                raise self._hung(self._call)
            call = self._call = _Call(what, fn, args, time.monotonic_ns())
            self._asked.notify()
        if not call.done.wait(self.timeout_ns * 1e-9):
            raise self._hung(call)
        if call.error is not None:
            raise call.error
        return call.result

    def hung_for_ns(self) -> int:
        """How long the call in progress has run; 0 when none is."""
        call = self._call
        return 0 if call is None or call.done.is_set() else max(1, time.monotonic_ns() - call.started_ns)

    def _hung(self, call: _Call) -> TimeoutError:
        return TimeoutError(f"lerobot {self.name}: {call.what} has not returned for "
                            f"{(time.monotonic_ns() - call.started_ns) * 1e-6:.0f} ms (limit "
                            f"{self.timeout_ns * 1e-6:.0f} ms)")

    def _serve(self) -> None:
        while True:
            with self._asked:
                while self._call is None or self._call.done.is_set():
                    self._asked.wait()
                call = self._call
            try:
                call.result = call.fn(*call.args)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller, who names it
                call.error = exc
            call.done.set()


class LeRobotBridge:
    """A connected LeRobot ``Robot`` behind cellguard's Robot calls; arrays in the profile's joint order, SI."""

    def __init__(self, robot, profile: Profile, units: ActionMap, dt_ns: int, clock=time.monotonic_ns,
                 lockstep: bool = False, timeout_s: float = READ_TIMEOUT_S, home: np.ndarray | None = None):
        if units.ee_actions:
            raise ConfigError("units map: end-effector entries cannot drive a LeRobot robot's joints; "
                              "map each action key to a joint")
        driven = {a.joint for a in units.joint_actions}
        undriven = [name for j, name in enumerate(profile.joint_names) if j not in driven]
        if undriven:  # a held joint read as its hold value, not where the robot is, and was never commanded
            raise ConfigError(f"units map: joints {', '.join(undriven)} have no action key; the bridge reads and "
                              f"commands every joint of a LeRobot robot through its key (no hold)")
        missing = [n for n in units.names if n not in robot.action_features]
        if missing:
            raise ConfigError(f"units map: actions {', '.join(missing)} are not action keys of LeRobot robot "
                              f"{robot.name!r}; its keys: {', '.join(robot.action_features)}")
        self.robot, self.profile, self.units, self.dt_ns = robot, profile, units, dt_ns
        self.clock = clock  # [ns] stamps of reads: monotonic, or (lockstep) one period per command
        self.lockstep = lockstep
        self._t_ns = 0
        if lockstep:
            self.clock = lambda: self._t_ns
        self.name = f"lerobot:{robot.name}"
        self.q_home = home  # (dof,) SI, or None: no retreat, no home cycle source
        self._kt = profile.array("torque_constant")
        self._current_keys = [f"{j}.current" for j in profile.joint_names]
        self._last: State | None = None
        self._obs: dict = {}
        self._calls = RobotCalls(robot.name, timeout_s)
        if not robot.is_connected:
            robot.connect()  # on this thread: a first connection may ask the operator to calibrate

    # -- Robot -------------------------------------------------------------------------
    def read(self) -> State:
        """One ``get_observation``: positions in SI, velocity from the previous read, current if reported."""
        try:
            obs = self._calls("get_observation", self.robot.get_observation)
        except TimeoutError as exc:
            raise RobotLinkError("robot_read_timeout", str(exc), lost=self._lost()) from None
        except Exception as exc:  # noqa: BLE001 - a dead bus is an error the loop must see, by name
            raise BridgeError(f"lerobot {self.robot.name}: get_observation failed: {type(exc).__name__}: {exc}") from exc
        t = self.clock()
        q = self._to_si(obs, self._last.q if self._last is not None else np.zeros(self.profile.dof))
        if self._last is not None and t > self._last.t_ns:
            qd = (q - self._last.q) / ((t - self._last.t_ns) * 1e-9)
        else:
            qd = np.zeros_like(q)
        current = np.array([float(obs.get(k, 0.0)) for k in self._current_keys])
        self._last = State(t, q, qd, current * self._kt, current)
        self._obs = obs
        return self._last

    def write(self, setpoint: np.ndarray) -> np.ndarray:
        """Send joint targets (dof,) [SI]; return what ``send_action`` says it sent, in SI."""
        setpoint = np.asarray(setpoint, dtype=np.float64)
        if setpoint.shape != (self.profile.dof,) or not np.isfinite(setpoint).all():
            raise BridgeError(f"lerobot {self.robot.name}: refused setpoint {setpoint.tolist()}: expected "
                              f"{self.profile.dof} finite joint positions; nothing was sent")
        values = self.units.to_policy_state(setpoint)
        action = {name: float(v) for name, v in zip(self.units.names, values)}
        try:
            sent = self._calls("send_action", self.robot.send_action, action)
        except TimeoutError as exc:
            raise RobotLinkError("robot_write_failed", f"{exc}; the setpoint may still be sent",
                                 lost=self._lost()) from None
        except Exception as exc:  # noqa: BLE001
            raise BridgeError(f"lerobot {self.robot.name}: send_action failed: {type(exc).__name__}: {exc}") from exc
        self._t_ns += self.dt_ns
        return self._to_si(sent, setpoint)

    def safety(self) -> SafetyInputs:
        """LeRobot robots report no safety controller; a certified one is wired to the cell, not read here."""
        return SafetyInputs()

    @property
    def digital_inputs(self) -> tuple[str, ...]:
        """The keys of the robot's observation, any of which can be read as a 0/1 input."""
        return tuple(self.robot.observation_features)

    def digital_input(self, name: str) -> bool:
        """A 0/1 reading the robot reports under ``name`` (a part-done signal wired into its
        observation), from the last read."""
        if name not in self.robot.observation_features:
            raise BridgeError(f"lerobot {self.robot.name}: no input {name!r} in its observation; "
                              f"it reports: {', '.join(self.robot.observation_features)}")
        return bool(self._obs.get(name, 0.0))

    def set_power(self, on: bool) -> None:
        """Torque on or off through the robot's motor bus where it has one (LeRobot's motor arms do)."""
        bus = getattr(self.robot, "bus", None)
        if bus is None:
            raise BridgeError(f"lerobot {self.robot.name}: no motor bus to switch torque; "
                              "remove power with the cell's safety controller")
        try:
            self._calls("torque on" if on else "torque off", bus.enable_torque if on else bus.disable_torque)
        except TimeoutError as exc:
            raise BridgeError(f"{exc}; remove power with the cell's safety controller") from None

    # -- What a loop needs besides read/write ----------------------------------------------
    def observe(self) -> Observation:
        """The last read as the policy sees it: joints plus the robot's other float readings by name."""
        state = self._last if self._last is not None else self.read()
        groups: dict[str, list[float]] = {}
        for key, value in self._obs.items():
            stem, _, axis = key.rpartition(".")
            if axis in _AXES and isinstance(value, (int, float)):
                groups.setdefault(stem, []).append(float(value))
        return Observation(state.t_ns, state.q, state.qd, {k: np.array(v) for k, v in groups.items()})

    def context(self) -> dict:
        return {"cell": self.name, "lerobot_robot": {"type": self.robot.name, "id": self.robot.id},
                "units_map": list(self.units.names)}

    def close(self) -> None:
        """Disconnect, unless a call still hangs on the bus (the disconnect would hang the process with it)."""
        if self.robot.is_connected and not self._calls.hung_for_ns():
            self.robot.disconnect()

    def _lost(self) -> bool:
        """A call hung four times its limit: the robot is gone, as a server silent that long is."""
        return self._calls.hung_for_ns() > 4 * self._calls.timeout_ns

    def _to_si(self, values: dict, fallback: np.ndarray) -> np.ndarray:
        """Joint vector (dof,) SI from a LeRobot dict; joints the dict leaves out keep ``fallback``."""
        names = self.units.names
        row = np.array([float(values[n]) if n in values else np.nan for n in names])
        out = self.units.to_robot(np.nan_to_num(row)[None], fallback)[0]
        for a in self.units.joint_actions:
            if np.isnan(row[a.column]):
                out[a.joint] = fallback[a.joint]
        return out


def make_lerobot_robot(arg: str, read_timeout_s: float = READ_TIMEOUT_S,
                       cell: str | None = None) -> LeRobotBridge:
    """``TYPE?opt=value&...``: LeRobot's robot ``TYPE`` with its config options, plus ``units``/``embodiment``/``hz``.
    ``cell``: the cell the scenario names, which must be one of the robot this bridge drives (None: not checked)."""
    where = f"robot: lerobot:{arg.partition('?')[0]}".rstrip(":")  # no type: "robot: lerobot: missing target"
    robot_type, options = split_options(arg, None, where, "lerobot:TYPE?port=...&id=...")  # the rest go to TYPE's config
    ours = {k: options.pop(k) for k in list(options) if k in OPTIONS}
    name = ours.get("embodiment", TYPE_EMBODIMENT.get(robot_type))
    if name not in EMBODIMENTS:
        what = (f"embodiment={name!r} is not one cellguard knows" if "embodiment" in ours
                else "no embodiment profile for this type; give ?embodiment=NAME")
        raise ConfigError(f"{where}: {what} (known: {', '.join(EMBODIMENTS)})")
    from cellguard.embodiment.action_map import load_action_map  # the units map is an action map (data, checked)

    embodiment = EMBODIMENTS[name]()
    profile = load_profile(embodiment.load_model(), embodiment.profile)
    if cell is not None:
        _refuse_other_robot(cell, profile, where)
    units = load_action_map(Path(ours.get("units", embodiment.units)), profile)
    hz = bounded_float(ours.get("hz", 50.0), f"{where}: option hz", 1.0, 1000.0)
    lockstep = ours.get("lockstep", "0")
    if lockstep not in ("0", "1"):
        raise ConfigError(f"robot: lerobot: option lockstep must be 0 or 1, got {lockstep!r}")
    home = _home(ours["home"], profile, units) if "home" in ours else None
    return LeRobotBridge(lerobot_robot(robot_type, options), profile, units, round(1e9 / hz), lockstep=lockstep == "1",
                         timeout_s=read_timeout_s, home=home)


def _refuse_other_robot(cell: str, profile: Profile, where: str) -> None:
    """ScenarioError unless the scenario's ``cell`` guards the joints ``profile`` does, in its order, before LeRobot's
    robot is built or connected: the run drove and guarded this robot while its summary named the scenario's cell
    (an SO-101 run filed as the arm cell's), as a sim-server serving another cell is refused. Compared by joints,
    not by the profile's ``robot`` name: a plugin cell of the same robot gives its own profile its own name."""
    from cellguard.robot.registry import make_cell

    named = make_cell(cell).profile
    if named.joint_names != profile.joint_names:
        raise ScenarioError(f"cell: the scenario names {cell!r}, whose joints are {', '.join(named.joint_names)}, but "
                            f"{where} drives robot {profile.robot!r}, whose joints are {', '.join(profile.joint_names)}; "
                            "name a cell of that robot, or a bridge to the scenario's robot")


def _home(text: str, profile: Profile, units: ActionMap) -> np.ndarray:
    """``?home=v1,v2,...`` in the units map's order and units, as a joint pose (dof,) SI inside the limits (one
    within ``HOME_SLACK`` past a limit is put at the limit)."""
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        values = np.array([np.nan])
    if len(values) != len(units.names) or not np.isfinite(values).all():
        raise ConfigError(f"robot: lerobot: option home={text[:80]!r} must be {len(units.names)} finite numbers, "
                          f"comma-separated, for {', '.join(units.names)}")
    q = units.to_robot(values[None], np.zeros(profile.dof))[0]
    lo, hi = profile.q_min, profile.q_max
    j = profile.first_outside(q, HOME_SLACK)
    if j is not None:
        given = {a.joint: f" ({a.name} {values[a.column]:g})" for a in units.joint_actions}.get(j, "")
        raise ConfigError(f"robot: lerobot: option home puts {profile.joint_names[j]} at {q[j]:.6g}{given}, "
                          f"outside its limits [{lo[j]:.6g}, {hi[j]:.6g}]")
    return np.clip(q, lo, hi)


def lerobot_robot(robot_type: str, options: dict[str, str]):
    """LeRobot's own robot for ``robot_type``, its config parsed from ``options`` by draccus (not connected)."""
    try:
        import draccus
        from lerobot.robots import RobotConfig, make_robot_from_config
        from lerobot.utils.import_utils import register_third_party_plugins
    except ImportError:
        raise ConfigError("robot: lerobot: needs LeRobot; install it with pip install 'cellguard[lerobot]' "
                          "(several GB: it brings torch)") from None
    register_third_party_plugins()
    if robot_type not in RobotConfig.get_known_choices():
        _import_builtin_robots()
    known = RobotConfig.get_known_choices()
    if robot_type not in known:
        raise ConfigError(f"robot: lerobot: unknown robot type {robot_type!r}; known: {', '.join(sorted(known))}")
    config_class = RobotConfig.get_choice_class(robot_type)
    try:
        config = draccus.parse(config_class, args=[f"--{k}={v}" for k, v in options.items()])
    except SystemExit:  # argparse's way of refusing an option
        fields = sorted(getattr(config_class, "__dataclass_fields__", {}))
        raise ConfigError(f"robot: lerobot:{robot_type}: options {sorted(options)} do not fit its config; "
                          f"fields: {', '.join(fields)}") from None
    return make_robot_from_config(config)


def _import_builtin_robots() -> None:
    """LeRobot registers a built-in robot's config when its subpackage is imported, as its scripts do."""
    import importlib
    import pkgutil

    import lerobot.robots

    for module in pkgutil.iter_modules(lerobot.robots.__path__):
        if module.ispkg:
            try:
                importlib.import_module(f"lerobot.robots.{module.name}")
            except Exception:  # noqa: BLE001, S112 - a robot whose optional SDK is absent cannot be built anyway
                continue
