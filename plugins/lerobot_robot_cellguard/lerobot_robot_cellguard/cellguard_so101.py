"""``CellguardSO101``: the so101-pick-place cell as a LeRobot ``Robot`` that behaves like LeRobot's SO follower.

It speaks LeRobot's units (degrees with mid-range zero, gripper 0..100), converted by the same
units map file the cellguard bridge uses; ``send_action`` caps each goal with LeRobot's own
``ensure_safe_goal_position`` when ``max_relative_target`` is set, clips to the servo's position
range, refuses a non-finite goal (LeRobot's Feetech bus raises on one too), writes the goal and
advances the simulation by ``action_period_s``, and returns the action really sent.
Observations add motor current (``<motor>.current`` [A]), the cell camera's readings
(``part_in_camera.x`` ... [m]) and the cell's part-done input ``cycle_done`` (0/1), which a real
SO follower does not report. The cell runs its own task: the next part arrives as one is placed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lerobot.robots import Robot
from lerobot.robots.utils import ensure_safe_goal_position
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from cellguard.embodiment.action_map import load_action_map
from cellguard.robot.own_task import OwnTask
from cellguard.robot.so101_cell import ASSETS, SO101PickPlace
from cellguard.scenario import load_scenario
from lerobot_robot_cellguard.config_cellguard_so101 import CellguardSO101Config

class SimulatedTorque:
    """The two torque calls of LeRobot's motor buses (``enable_torque``/``disable_torque``) on the simulated drives."""

    def __init__(self, cell: SO101PickPlace):
        self.cell = cell

    def enable_torque(self) -> None:
        self.cell.set_power(True)

    def disable_torque(self) -> None:
        self.cell.set_power(False)  # actuators off, joints braked


MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
MEASUREMENTS = ("part_in_camera", "fixture_in_camera")


class CellguardSO101(Robot):
    """A simulated SO-101 follower; ``cell`` is the simulated cell once connected (its task, its faults),
    ``bus`` switches its torque as a LeRobot motor bus does."""

    config_class = CellguardSO101Config
    name = "cellguard_so101"

    def __init__(self, config: CellguardSO101Config):
        super().__init__(config)
        self.config = config
        self.cell: SO101PickPlace | None = None
        self._keys = tuple(f"{m}.pos" for m in MOTORS)

    @property
    def observation_features(self) -> dict:
        return {**{k: float for k in self._keys}, **{f"{m}.current": float for m in MOTORS},
                **{f"{n}.{a}": float for n in MEASUREMENTS for a in "xyz"}, "cycle_done": float}

    @property
    def action_features(self) -> dict:
        return {k: float for k in self._keys}

    @property
    def is_connected(self) -> bool:
        return self.cell is not None

    @property
    def is_calibrated(self) -> bool:
        return True  # the model's zeros are LeRobot's mid-range zeros

    def connect(self, calibrate: bool = True) -> None:
        if self.cell is not None:
            raise DeviceAlreadyConnectedError(f"{self} already connected")
        self.cell = SO101PickPlace(seed=self.config.seed)
        faults = load_scenario(Path(self.config.faults)).faults if self.config.faults else ()
        self.task = OwnTask(self.cell, faults)
        self.bus = SimulatedTorque(self.cell)
        self.units = load_action_map(self.config.units or ASSETS / "so101_lerobot_units.yaml", self.cell.profile)
        if self.units.names != self._keys:
            raise ValueError(f"units map actions {self.units.names} must be {self._keys}, in that order")
        self._steps = max(1, round(self.config.action_period_s * 1e9 / self.cell.dt_ns))
        lo, hi = self.cell.model.actuator_ctrlrange[self.cell.drives.act].T
        self._range = np.sort([self.units.to_policy_state(lo), self.units.to_policy_state(hi)], axis=0)

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def get_observation(self) -> dict:
        self._check()
        state = self.cell.read()
        obs = dict(zip(self._keys, self.units.to_policy_state(state.q).tolist()))
        obs.update({f"{m}.current": float(c) for m, c in zip(MOTORS, state.current)})
        seen = self.cell.observe().measurements
        obs.update({f"{n}.{a}": float(v) for n in MEASUREMENTS for a, v in zip("xyz", seen[n])})
        obs["cycle_done"] = float(self.task.cycle_done(state.t_ns))
        return obs

    def send_action(self, action: dict) -> dict:
        """Command joint goals in LeRobot units; return the goals really sent (capped, clipped)."""
        self._check()
        goal = {k: float(v) for k, v in action.items() if k in self._keys}
        if not all(np.isfinite(list(goal.values()))):
            raise ValueError(f"{self}: non-finite goal position {goal}; nothing written")
        q_now = self.cell.read().q
        present = dict(zip(self._keys, self.units.to_policy_state(q_now).tolist()))
        if self.config.max_relative_target is not None:
            cap = self.config.max_relative_target
            if isinstance(cap, dict):
                cap = {f"{k}.pos": v for k, v in cap.items() if f"{k}.pos" in goal}
            goal = ensure_safe_goal_position({k: (g, present[k]) for k, g in goal.items()}, cap)
        row = np.array([goal.get(k, present[k]) for k in self._keys])
        row = np.clip(row, self._range[0], self._range[1])  # the servo's position limits
        sent = {k: float(v) for k, v in zip(self._keys, row) if k in goal}
        self.cell.write(self.units.to_robot(row[None], q_now)[0])
        for _ in range(self._steps):
            self.cell.step()
            self.task.poll(self.cell.t_ns)
        return sent

    def disconnect(self) -> None:
        self._check()
        self.cell = None

    def _check(self) -> None:
        if self.cell is None:
            raise DeviceNotConnectedError(f"{self} is not connected")
