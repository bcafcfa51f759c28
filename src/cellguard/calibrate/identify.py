"""Identify a cell's drive and joint parameters from its own record, starting from the nominal MJCF.

Method (linear in the unknowns, so one least-squares solve with intervals, no rollouts):

1. Command delay and servo gain: a position drive's effort is ``kp (q_cmd(t - delay) - q) - kv qd``.
   For every candidate delay (whole servo periods up to ``MAX_DELAY_S``) that regression is
   solved per joint; the delay with the smallest residual wins (a cross-correlation of the
   command with the effort it causes, free of the lag the arm's own dynamics adds).
2. Joint parameters: the measured torque (current x torque constant) minus the rigid-body
   torque of the nominal model (``mj_inverse`` with armature, damping, dry friction and
   constraints removed) is regressed on ``qdd`` (armature), ``qd`` (damping), ``sign(qd)``
   (dry friction) per joint, and on the torque one kilogram more at the payload body needs
   (payload, shared by all joints). Samples slower than ``MIN_SPEED`` are left out (dry friction
   is set-valued there). The implicit integrator's velocity derivative terms add
   ``dt (kv + damping)`` to the effective armature; it is taken off.

Intervals are simultaneous 95 % intervals: all the reported parameters of one fit lie inside
their intervals together with probability 0.95 (Sidak: each at level ``0.95 ** (1/m)`` for ``m``
parameters), which is the claim "each truth inside its interval" makes; a marginal 95 % interval
misses one parameter in twenty by design. The standard errors are heteroskedasticity-consistent
(White: the joints' current noise differs with their torque constants) and corrected for residuals
correlated in time by an effective sample size (``_ess_factor``: a model mismatch that follows the
motion makes neighbouring residuals alike, and the textbook error, which assumes they are not,
would understate the spread). A column that the data does not excite (near-zero norm or in the near-null space) is
"not identifiable"; so are a joint's friction and damping unless it moved both ways (``moves_both_ways``). The
delay's interval is the search's resolution (one servo period either side).

The method has a small bias of its own (the fit's finite-difference torque model against the
integrator's step, dry friction near velocity reversals): noise explains the spread, not the offset
(the arm's wrist_roll armature came out 3.8 standard errors from its truth). ``method_bias`` measures it
for each parameter by re-identifying a noise-free replay of the same commands on the cell's model
with the identified values (``bootstrap.simulate``), and each interval is widened by ``|bias|`` (the
delay's by whole servo periods); the JSON reports it per parameter (``method_bias``). It doubles the
fit's time. Not done where a floating base moved freely (the replay cannot reproduce foot forces).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np
from scipy import stats
from threadpoolctl import threadpool_limits

from cellguard.calibrate.torque_model import MIN_SPEED, hinge_joints, inverse_torques, rigid_model
from cellguard.dates import utc_day, utc_today
from cellguard.errors import ConfigError

PARAMS = ("friction", "armature", "damping", "kp", "delay", "payload")
UNITS = {"friction": "N*m", "armature": "kg*m^2", "damping": "N*m*s/rad", "kp": "N*m/rad", "delay": "s",
         "payload": "kg"}
MAX_DELAY_S = 0.03  # longest command delay searched [s]
MIN_TICKS = 200  # shortest stretch of servo-rate ticks used [ticks]
SATURATED = 0.95  # samples with effort beyond this fraction of the force range leave the drive regression
LEVEL = 0.95  # joint coverage of all reported intervals of one fit
ESS_LAGS = 100  # lags over which residual correlation is counted in the effective sample size [ticks]
NULL_EIG = 1e-10  # relative eigenvalue of the scaled normal matrix below which a direction is unexcited
BOTH_WAYS_TICKS = ESS_LAGS  # ticks a joint must move in each direction to identify its friction and damping


class CalibrationError(ConfigError):
    """Bad input to identification: a record it cannot use, a parameter the model does not have."""


@dataclass(frozen=True)
class Estimate:
    """One identified parameter; ``low``/``high`` the 95 % interval (None when not identifiable)."""

    parameter: str
    joint: str | None
    value: float | None
    unit: str
    nominal: float
    low: float | None
    high: float | None

    @property
    def identifiable(self) -> bool:
        return self.value is not None and self.low is not None

    def to_dict(self) -> dict:
        out = {"parameter": self.parameter, "joint": self.joint, "value": self.value, "unit": self.unit,
               "nominal": self.nominal, "interval": [self.low, self.high] if self.identifiable else None}
        if not self.identifiable:
            out["note"] = "not identifiable from this data"
        return out


@dataclass(frozen=True)
class Segment:
    """Ticks of one record: (n, dof) arrays in profile joint order; ``tau`` the measured torque [N*m] (NaN on a
    joint not fitted whose drive reports no current)."""

    q: np.ndarray
    qd: np.ndarray
    q_cmd: np.ndarray
    tau: np.ndarray
    record_id: str
    on_stand: bool = False  # the record's context says the base was held on a stand (``excite --stand``)


def model_params(cell) -> tuple[str, ...]:
    """The parameters ``cell``'s model has: ``payload`` needs a body named ``tool``."""
    has_tool = mujoco.mj_name2id(cell.model, mujoco.mjtObj.mjOBJ_BODY, "tool") >= 0
    return tuple(p for p in PARAMS if p != "payload" or has_tool)


def parse_params(text: str | None, cell) -> tuple[str, ...]:
    """``friction,armature`` -> the names, each one ``cell``'s model has (None: all of them)."""
    allowed = model_params(cell)
    if text is None:
        return allowed
    names = tuple(p.strip() for p in text.split(",") if p.strip())
    for name in names:
        if name not in allowed:
            raise CalibrationError(f"--params: {name!r} is not a parameter of the {cell.name} model; "
                                   f"allowed: {', '.join(allowed)}")
    if not names:
        raise CalibrationError(f"--params: empty; allowed: {', '.join(allowed)}")
    return names


ONLY = ("friction", "damping", "armature")  # what ``--only JOINT,PARAM`` re-fits


def parse_only(items: list[str], cell) -> list[tuple[str, str]]:
    """``["elbow,friction"]`` -> [(joint, parameter)], each a hinge joint of ``cell`` and one of ``ONLY``, each
    once (a pair given twice would be reported twice and counted twice in the simultaneous intervals)."""
    joints = [cell.profile.joint_names[i] for i in hinge_joints(cell)]
    pairs = []
    for item in items:
        parts = [p.strip() for p in item.split(",")]
        if len(parts) != 2:
            raise CalibrationError(f"--only: {item!r} is not JOINT,PARAM (e.g. elbow,friction)")
        joint, param = parts
        if joint not in joints:
            raise CalibrationError(f"--only: {joint!r} is not a joint of the {cell.name} model; allowed: "
                                   f"{', '.join(joints)}")
        if param not in ONLY:
            raise CalibrationError(f"--only: {param!r} cannot be re-fitted alone; allowed: {', '.join(ONLY)}")
        if (joint, param) not in pairs:
            pairs.append((joint, param))
    return pairs


def moves_both_ways(qd: np.ndarray) -> np.ndarray:
    """Per column of ``qd`` (n, joints): whether the joint moved faster than ``MIN_SPEED`` each way on at least
    ``BOTH_WAYS_TICKS`` ticks, which its friction and damping need. Dry friction is ``F sign(qd)``: what tells it
    from a torque the model misses that keeps its sign whichever way the joint turns (a gravity or payload error,
    a current offset) is its jump where the velocity changes sign. Moving one way only, ``sign(qd)`` is a constant,
    friction is the intercept of torque against speed extrapolated to zero and damping its slope, both taking up
    any such error (a 1 s record: shoulder_lift damping 0.38 [0.33, 0.43], truth 0.5). Each way at least one
    correlation length of the residuals (``ESS_LAGS``): fewer ticks are one correlated look at that direction,
    whose error the interval cannot bound."""
    return np.minimum((qd > MIN_SPEED).sum(axis=0), (qd < -MIN_SPEED).sum(axis=0)) >= BOTH_WAYS_TICKS


def refit(segments: list[Segment], cell, pairs: list[tuple[str, str]], terms) -> dict:
    """Re-fit just ``pairs`` (joint, parameter), every other term held at ``terms`` (a ``JointTerms``): the
    residual of that model regressed on the parameter's own column. One column is excited by far less
    motion than all of them together, so production cycles usually do."""
    from cellguard.calibrate.torque_model import TorqueModel

    if floating_base(cell) and not all(s.on_stand for s in segments):
        raise CalibrationError(f"--only: {cell.name}'s base moved freely in these records; re-fit from a record "
                               f"taken on a stand (`cellguard excite {cell.name} --stand`)")
    with threadpool_limits(limits=1, user_api="blas"):  # tall, thin matrices: see identify
        return _refit(segments, cell, pairs, TorqueModel(cell, terms), terms)


def _refit(segments, cell, pairs, model, terms) -> dict:
    current = {"friction": terms.friction, "damping": terms.damping, "armature": terms.armature}
    estimates = []
    for joint, param in pairs:
        k = model.names.index(joint)
        i = model.joints[k]
        rows = _Rows()
        for s in segments:
            v = s.qd[:-1, i]
            moving = np.abs(v) > MIN_SPEED
            column = {"friction": np.sign(v), "damping": v, "armature": np.diff(s.qd[:, i]) / model.dt}[param]
            rows.add(column[moving][:, None], (s.tau[1:, i] - model.torque(s.q, s.qd)[:, k])[moving])
        x, y = rows.stacked()
        if len(y) < 100:
            raise CalibrationError(f"--only {joint},{param}: {joint} moves faster than {MIN_SPEED} rad/s in only "
                                   f"{len(y)} ticks of these records; record more cycles at full rate")
        beta, cov = _ols(x, y)
        value = float(current[param][k] + beta[0])
        nominal = float(_nominal(cell.model, param, cell.drives.dadr[i]))
        one_way = param != "armature" and not moves_both_ways(np.concatenate([s.qd[:-1, i] for s in segments]))
        estimates.append(Fitted(param, joint, value, np.inf if one_way else float(np.sqrt(cov[0, 0])), nominal))
    final = with_intervals(estimates)
    rows = [e.to_dict() for e in final]
    return {"robot": cell.name, "records": sorted({s.record_id for s in segments}),
            "samples": int(sum(len(s.q) for s in segments)),
            "method": "re-fit of one term on the residual of the profile's model (mj_inverse)",
            "payload_held_kg": float(terms.payload_kg),  # the calibration's, in the model and in --write's MJCF
            "interval": interval_note(estimates), "estimates": rows,
            "warnings": unexcited_warnings(final, cell) + negative_warnings(rows)}


def unexcited_warnings(estimates: list[Estimate], cell) -> list[str]:
    """One warning naming each term the records do not excite, joint by joint (a list of parameter names alone read
    as every joint's, while ``--write`` stored the other joints' values), and what ``--write`` does with them."""
    terms: dict[str | None, list[str]] = {}
    for e in estimates:
        if not e.identifiable:
            terms.setdefault(e.joint, []).append(e.parameter)
    if not terms:
        return []
    named = "; ".join(f"{joint} {', '.join(params)}" if joint else ", ".join(params) for joint, params in terms.items())
    return [f"{named}: not excited by these records (production cycles rarely are): not identified, and --write keeps "
            f"the profile's values for them; `cellguard excite {cell.name}` records a trajectory that excites them"]


NON_NEGATIVE = ("friction", "damping", "armature")  # a value below zero is no physical joint term


def negative_values(rows: list[dict]) -> list[dict]:
    """The identified rows (``Estimate.to_dict``) of ``NON_NEGATIVE`` parameters whose value is below zero."""
    return [e for e in rows if e["parameter"] in NON_NEGATIVE and e["interval"] is not None and e["value"] < 0.0]


def describe_value(e: dict) -> str:
    """``elbow friction -2.303 N*m [-2.4, -2.2]``: one identified row in words."""
    lo, hi = e["interval"]
    return f"{e['joint']} {e['parameter']} {e['value']:.4g} {e['unit']} [{lo:.4g}, {hi:.4g}]"


def negative_warnings(rows: list[dict]) -> list[str]:
    """One warning for the rows whose friction, damping or armature came out negative (a model that does not fit
    the robot, or too little motion), which ``identify --write`` does not store."""
    bad = negative_values(rows)
    if not bad:
        return []
    return [f"{'; '.join(describe_value(e) for e in bad)}: below zero, which no joint has; the model does not fit "
            "these records (or they move too little): check the records and the profile before using these values"]


def floating_base(cell) -> bool:
    """Whether a free joint sits above a profiled joint: inverse dynamics then needs the base's motion
    and the foot forces, which a record does not carry, unless the base was held on a stand."""
    m = cell.model
    for name in cell.profile.joint_names:
        body = m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)]
        while body > 0:
            for j in range(m.body_jntadr[body], m.body_jntadr[body] + m.body_jntnum[body]):
                if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                    return True
            body = m.body_parentid[body]
    return False


def record_robot(path: Path) -> str:
    """The robot a record is of (its context's ``cell``)."""
    from cellguard.record.reader import open_record

    with open_record(path) as rec:
        robot = rec.context.get("cell")
    if not robot:
        raise CalibrationError(f"{path}: the record's context names no robot (cell); pass --cell")
    return robot


def measured_on(paths: list[Path]) -> str:
    """The day the records were measured: the UTC date of the latest record's start (``YYYY-MM-DD``). Not the
    day identify runs, nor a local date: west of UTC a local ``today`` stamped the day before the record."""
    from cellguard.record.reader import open_record

    starts = []
    for path in paths:
        with open_record(path) as rec:
            starts.append(rec.start_wall_ns)
    if min(starts) <= 0:  # a record without a wall-clock epoch: the day it is read on, in UTC
        return utc_today().isoformat()
    return utc_day(max(starts)).isoformat()


def refuse_ahead(day: str, what: str, fix: str) -> None:
    """CalibrationError where ``day`` (YYYY-MM-DD, UTC) lies after tomorrow by this host's clock (a site east of
    UTC is a day ahead): the clock that stamped it ran ahead, or this host's is behind. Checked where a measured
    date is made, never where a profile is loaded: a profile must load on any host at any time (one dated by a
    fast clock stopped the cell once NTP set it right; a host whose clock reset to 1970 could load none)."""
    today = utc_today()
    if datetime.date.fromisoformat(day) > today + datetime.timedelta(days=1):
        raise CalibrationError(f"{what} is {day}, after tomorrow (today is {today.isoformat()}, UTC, by this "
                               f"host's clock): {fix}")


def load_segments(paths: list[Path], cell, cycle: int | None = None) -> list[Segment]:
    """Each record's full-rate ticks (of ``cycle`` only, if given): ``load_records`` without the healths."""
    return load_records(paths, cell, cycle)[0]


def load_records(paths: list[Path], cell, cycle: int | None = None,
                 write: bool = False) -> tuple[list[Segment], list[tuple[Path, object]], list[str]]:
    """Each record's full-rate ticks (of ``cycle`` only, if given), checked to be of ``cell``'s robot and
    to carry motor current on every joint fitted (a gripper's may be missing), split where a tick is missing; each
    record's ``Health`` (what a full read found), for the caller to warn about a record that is not whole; and one
    warning per record whose ticks were left out for a fitted joint's current it did not report (``left_out``).
    A record given twice (its id, or for a record without one its file, under any spelling) is refused: it would
    count its ticks twice and shrink every interval. So is one that started after tomorrow (``refuse_ahead``), and
    one holding a value no measurement gives (``refuse_unmeasured``). A record whose servo-rate ticks are only the
    windows kept around its events (``event_windows``) is refused for ``write`` and warned about otherwise."""
    from cellguard.record.reader import open_record, record_file

    segments, healths, warnings, seen = [], [], [], {}
    for n, path in enumerate(paths, start=1):
        with open_record(path) as rec:
            record_id = rec.record_id or str(path)
            key = rec.record_id or str(record_file(path).resolve())
            if key in seen:
                k, first = seen[key]
                raise CalibrationError(f"{path} (record argument {n}) is the same record as {first} (argument {k}), "
                                       f"run {record_id}; give each record once")
            seen[key] = (n, path)
            robot = rec.context.get("cell")
            if robot != cell.name:
                raise CalibrationError(f"{path}: a record of robot {robot!r}; the model is {cell.name!r}")
            if rec.start_utc is not None:  # before the fit: its date would be the calibration's
                refuse_ahead(rec.start_utc[:10], f"{path}: the start of run {record_id}",
                             "the clock that recorded it ran ahead (or this host's is behind), so a calibration "
                             "would be dated after today; record again with the clock set (NTP)")
            ticks = rec.ticks(cycle=cycle, rate="all")
            on_stand = rec.context.get("mount") == "stand"
            windows = event_windows(path, record_id, rec.context, cell)
            healths.append((path, rec.health()))
        if tuple(ticks.joints) != tuple(cell.profile.joint_names):
            raise CalibrationError(f"{path}: joints {list(ticks.joints)}; the model has "
                                   f"{list(cell.profile.joint_names)}")
        joints = hinge_joints(cell)  # the joints fitted: a gripper's current is not needed
        tau = ticks.current * cell.profile.array("torque_constant")
        missing = [cell.profile.joint_names[i] for i in joints if not np.isfinite(tau[:, i]).any()]
        if missing:
            raise CalibrationError(f"{path}: the record has no motor current on {', '.join(missing)}; identification "
                                   "needs the current of every joint it fits")
        refuse_unmeasured(path, record_id, ticks, cell.profile, joints)
        keep = ~np.isnan(tau[:, joints]).any(1)
        t_ns = ticks.t_ns
        # contiguous runs of servo-rate ticks (a decimated stream or a gap splits them)
        step = np.concatenate([[False], (np.diff(t_ns) == cell.dt_ns) & keep[1:] & keep[:-1]])
        starts = np.flatnonzero(~step)
        own = [Segment(ticks.q_meas[a:b], ticks.qd_meas[a:b], ticks.q_cmd[a:b], tau[a:b], record_id, on_stand)
               for a, b in zip(starts, np.append(starts[1:], len(t_ns))) if b - a >= MIN_TICKS]
        said = left_out(path, record_id, ticks, joints, keep, sum(len(s.q) for s in own))
        if not own:
            raise CalibrationError(f"{path}: no stretch of {MIN_TICKS} ticks at the servo rate; " + (
                said[0].removeprefix(f"{path}: ") if said else "record at full rate (`cellguard excite` does)"))
        if windows and write:
            raise CalibrationError(f"--write: {windows} (nothing written)")
        segments += own
        warnings += said + ([f"{windows} (the fit's values and intervals do not hold)"] if windows else [])
    return segments, healths, warnings


def event_windows(path: Path, record_id: str, context: dict, cell) -> str | None:
    """Why a record's servo-rate ticks cannot be fitted, or None: a run record decimated below the servo rate keeps
    them only in windows around its events and failed cycles, which are contact, stops and recoveries, and the fit's
    model is free motion without contact (a pick-and-place run's windows fitted wrist_flex armature 0.04988 [0.04982,
    0.04995], truth 0.05; leaving out 1.5 s around each stop did not help: the contact is in every cycle). A record
    that keeps every tick (``excite``'s; a decimated rate the writer's rule takes every tick at,
    ``decimation_stride``) is fitted whole."""
    from cellguard.record.writer import decimation_stride

    hz = (context.get("record") or {}).get("decimated_hz")
    if not isinstance(hz, (int, float)) or isinstance(hz, bool) or hz <= 0 or decimation_stride(cell.dt_ns, hz) == 1:
        return None
    return (f"{path}: run {record_id} is decimated to {hz:g} Hz and keeps the servo rate only in windows around its "
            f"events (contact, stops, recoveries), chosen by what went wrong, which the fit's model (free motion) "
            f"does not describe: identify from `cellguard excite {cell.name}` records")


# the tick fields the fit reads, in words (position, velocity and setpoint enter every joint's inverse dynamics)
FITTED_FIELDS = {"q_meas": "measured position", "qd_meas": "measured velocity", "q_cmd": "setpoint sent",
                 "current": "motor current"}
SPEED_BOUND = 100.0  # a measured velocity beyond this many times its joint's limit is no measurement
RANGE_BOUND = 10.0  # nor a position or setpoint beyond the joint's range by this many times its width
EFFORT_BOUND = 100.0  # nor a current whose torque is beyond this many times the joint's effort limit


def refuse_unmeasured(path: Path, record_id: str, ticks, profile, fitted: list[int]) -> None:
    """CalibrationError naming the first tick (time, field, joint, value) of a value no sensor measured, and how many
    of that field's values are such: a position, velocity or setpoint that is not finite, a current of a fitted joint
    (of ``fitted``) that is infinite (NaN: a drive that did not report one, ``left_out``); a value beyond any the joint
    reaches (``SPEED_BOUND``, ``RANGE_BOUND``, ``EFFORT_BOUND``). Each is a bus or writer fault: one NaN velocity made
    the least-squares solve fail in a traceback ("SVD did not converge"), 3e38 rad/s on one tick of elbow was fitted
    as a measurement (armature -1.9e69 kg*m^2), a position of 3e38 rad wrote a kp of -4.7e-41, a current of 1e6 A
    flooded the terminal with MuJoCo's warnings. A joint not fitted (a gripper) reads whatever current it has."""
    fix = "check the drive's bus or the program that wrote the record, and record again"
    lo, hi = profile.q_min, profile.q_max
    far = RANGE_BOUND * (hi - lo)
    effort = profile.array("effort") * EFFORT_BOUND
    units = ["rad" if joint.kind == "hinge" else "m" for joint in profile.joints]
    speed = profile.array("velocity")
    torque = np.abs(ticks.current * profile.array("torque_constant"))
    for field, words in FITTED_FIELDS.items():
        values = getattr(ticks, field)
        if field == "current":
            bad, beyond = np.zeros_like(values, dtype=bool), np.zeros_like(values, dtype=bool)
            bad[:, fitted], beyond[:, fitted] = np.isinf(values[:, fitted]), torque[:, fitted] > effort[fitted]
            bound = lambda j: f"a torque beyond {EFFORT_BOUND:g} times its effort limit of {effort[j] / EFFORT_BOUND:g}"
        elif field == "qd_meas":
            bad, beyond = ~np.isfinite(values), np.abs(values) > SPEED_BOUND * speed
            bound = lambda j: f"beyond {SPEED_BOUND:g} times its limit of {speed[j]:g} {units[j]}/s"
        else:
            bad, beyond = ~np.isfinite(values), (values < lo - far) | (values > hi + far)
            bound = lambda j: f"beyond its range [{lo[j]:g}, {hi[j]:g}] {units[j]} by {RANGE_BOUND:g} times its width"
        if bad.any():
            k, j = np.argwhere(bad)[0]
            raise CalibrationError(f"{path}: run {record_id}'s {words} ({field}) of {ticks.joints[j]} is "
                                   f"{values[k, j]} at tick t_ns {ticks.t_ns[k]} ({int(bad.sum())} of {bad.size} "
                                   f"values not finite); identification needs a number on every tick: {fix}")
        if beyond.any():
            k, j = np.argwhere(beyond)[0]
            unit = "A" if field == "current" else units[j] + ("/s" if field == "qd_meas" else "")
            raise CalibrationError(f"{path}: run {record_id}'s {words} ({field}) of {ticks.joints[j]} is "
                                   f"{values[k, j]:g} {unit} at tick t_ns {ticks.t_ns[k]}, {bound(j)} "
                                   f"({int(beyond.sum())} of {beyond.size} values); no joint of the profile reads so: "
                                   f"{fix}")


def left_out(path: Path, record_id: str, ticks, joints: list[int], keep: np.ndarray, used: int) -> list[str]:
    """A warning saying how many ticks of a record the fit goes without (of its ``len(keep)``, ``used`` in its
    stretches) and why: a fitted joint (of ``joints``) whose drive reported no current on them (not ``keep``), and the
    stretches between them too short to fit. Before, the fit went on unsaid; then the warning counted the NaN ticks
    alone (67 said, 9901 of 20220 left out with the stretches between them)."""
    if keep.all():
        return []
    names = [ticks.joints[i] for i in joints if np.isnan(ticks.current[:, i]).any()]
    return [f"{path}: {len(keep) - used} of {len(keep)} ticks of run {record_id} left out: no motor current (NaN) on "
            f"{', '.join(names)} on {int((~keep).sum())} ticks from t_ns {ticks.t_ns[np.argmin(keep)]} (a drive "
            f"that did not report it), and the stretches between them shorter than {MIN_TICKS} ticks"]


def identify(segments: list[Segment], cell, params: tuple[str, ...]) -> dict:
    """Fit ``params`` of ``cell``'s hinge joints to ``segments``; a dict ready for JSON.

    BLAS runs on one thread here: the matrices are tall and thin (at most a few dozen columns), and on a
    shared two-core machine OpenBLAS's worker threads spin more than they compute (measured: 7.5 s of CPU
    against 0.9 s on one thread for 15 s of a quadruped's ticks)."""
    with threadpool_limits(limits=1, user_api="blas"):
        return _identify(segments, cell, params)


def _identify(segments: list[Segment], cell, params: tuple[str, ...]) -> dict:
    model = cell.model
    dt = float(model.opt.timestep)
    names = [cell.profile.joint_names[i] for i in hinge_joints(cell)]
    dadr = cell.drives.dadr[hinge_joints(cell)]
    wanted = [p for p in ("armature", "damping", "friction", "payload") if p in params]  # report these
    held = not floating_base(cell) or all(s.on_stand for s in segments)
    lag, fitted = _fit(segments, cell, wanted if held else [])
    bias_lag, bias = method_bias(segments, cell, lag, fitted, wanted) if held else (0, {})
    estimates: list[Estimate | Fitted] = []
    if "delay" in params:
        widen = abs(bias_lag)
        estimates.append(Estimate("delay", None, lag * dt, "s", 0.0, max(lag - 1 - widen, 0) * dt,
                                  (lag + 1 + widen) * dt))
    estimates += [replace(f, bias=bias.get((f.parameter, f.joint), 0.0)) for f in fitted
                  if f.parameter in params]
    warnings = []
    if wanted and not held:
        estimates += [Estimate(p, name, None, UNITS[p], float(_nominal(model, p, dadr[k])), None, None)
                      for p in wanted if p != "payload" for k, name in enumerate(names)]
        estimates += [Estimate("payload", None, None, "kg", 0.0, None, None)] if "payload" in wanted else []
        warnings.append(f"{', '.join(wanted)}: {cell.name}'s base moved freely in these records, which carry neither "
                        f"its motion nor the foot forces; `cellguard excite {cell.name} --stand` records the joints "
                        "with the body held on a stand")
    note = interval_note(estimates) + (BIAS_NOTE if held else "; no bias check (the base moved freely)")
    biases = {(e.parameter, e.joint): e.bias for e in estimates if isinstance(e, Fitted)}
    estimates = with_intervals(estimates)
    if not warnings:
        warnings += unexcited_warnings(estimates, cell)
    rows = []
    for e in estimates:
        row = e.to_dict()
        if e.identifiable and held:
            row["method_bias"] = bias_lag * dt if e.parameter == "delay" else biases.get((e.parameter, e.joint))
        rows.append(row)
    warnings += negative_warnings(rows)
    return {"robot": cell.name, "records": sorted({s.record_id for s in segments}),
            "samples": int(sum(len(s.q) for s in segments)), "method": "linear regression on mj_inverse (nominal MJCF)",
            "interval": note, "estimates": rows, "warnings": warnings}


BIAS_NOTE = ("; each widened by the method's bias, measured by re-identifying a noise-free simulation of the same "
             "commands on the model with the identified values")


def _fit(segments: list[Segment], cell, wanted: list[str], errors: bool = True) -> tuple[int, list[Fitted]]:
    """The delay [ticks] and the fitted kp of every hinge joint, with armature, damping and friction of every
    hinge joint (and the payload) when ``wanted`` names any joint parameter (all three are fitted together:
    each alone absorbs the others). ``errors=False`` leaves the standard errors at zero (a re-fit that only
    needs the values: a third of the fit's time)."""
    model = cell.model
    dt = float(model.opt.timestep)
    joints = hinge_joints(cell)
    names = [cell.profile.joint_names[i] for i in joints]
    dadr, act = cell.drives.dadr[joints], cell.drives.act[joints]
    kv_nom = -model.actuator_biasprm[act, 2]
    lag, drive = _drive_fit(segments, model, act, joints, errors)
    fitted = [Fitted("kp", name, value, se, float(model.actuator_gainprm[act[k], 0]))
              for k, (name, (value, se)) in enumerate(zip(names, drive))]
    if wanted:
        fitted += _joint_fit(segments, cell, joints, names, dadr, kv_nom, "payload" in wanted, dt, errors)
    return lag, fitted


def method_bias(segments: list[Segment], cell, lag: int, fitted: list[Fitted],
                wanted: list[str]) -> tuple[int, dict]:
    """The method's own error at the identified values: (delay [ticks], {(parameter, joint): value}), each the
    re-identified minus the identified value, from ``bootstrap.simulate``'s noise-free replay of the records'
    commands on the cell's model with ``fitted`` put in (same integrator, same servo period, same start states).

    Why noise-free: measured positions and velocities carry no noise and the current's noise enters the fit
    linearly, so the expected re-identified value of a noisy replay equals the noise-free one; leaving the
    noise out removes the replay's own scatter from the bias instead of adding to it.
    Why widen the interval by ``|bias|`` rather than subtract the bias from the estimate: the bias is measured
    at the identified values, not the true ones, and on a robot the simulator reproduces the method's
    discretisation error but not what the robot does that no model has; widening keeps the fitted value as
    measured and the interval a statement that holds under either view (truth within ``z se + |bias|``)."""
    from cellguard.calibrate.bootstrap import simulate

    values = {(f.parameter, f.joint): f.value for f in fitted}
    lag2, refitted = _fit(simulate(segments, cell, lag, values), cell, wanted, errors=False)
    return lag2 - lag, {(f.parameter, f.joint): f.value - values[(f.parameter, f.joint)] for f in refitted}


def _nominal(model: mujoco.MjModel, parameter: str, dof: int) -> float:
    return {"armature": model.dof_armature, "damping": model.dof_damping, "friction": model.dof_frictionloss,
            "payload": np.zeros(model.nv)}[parameter][dof]


def _drive_fit(segments, model, act, joints, errors: bool = True) -> tuple[int, list[tuple[float, float]]]:
    """(delay in ticks, [(kp, its standard error)] per joint) from effort = kp (cmd(k - lag) - q) - kv qd.

    The delay search compares each lag's relative residual from the 2 x 2 normal equations; the
    intervals come from one full least-squares solve at the chosen lag."""
    dt = float(model.opt.timestep)
    limit = model.actuator_forcerange[act, 1]

    def rows(lag: int, k: int, i: int) -> tuple[np.ndarray, np.ndarray]:
        out = _Rows()
        for s in segments:
            # row r's effort acts in the step from row r-1's state, on the command taken lag ticks before row r
            e = s.q_cmd[1:len(s.q) - lag, i] - s.q[lag:-1, i]
            y = s.tau[lag + 1:, i]
            ok = np.abs(y) < SATURATED * limit[k]
            out.add(np.column_stack([e, s.qd[lag:-1, i]])[ok], y[ok])
        return out.stacked()

    costs = []
    for lag in range(round(MAX_DELAY_S / dt) + 1):
        cost = 0.0
        for k, i in enumerate(joints):
            x, y = rows(lag, k, i)
            gram, xty, yy = x.T @ x, x.T @ y, float(y @ y)
            beta = np.linalg.lstsq(gram, xty, rcond=None)[0]
            cost += max(yy - float(xty @ beta), 0.0) / max(yy, 1e-300)
        costs.append(cost)
    lag = int(np.argmin(costs))
    fits = []
    for k, i in enumerate(joints):
        beta, cov = _ols(*rows(lag, k, i), errors)
        fits.append((float(beta[0]), float(np.sqrt(cov[0, 0]))))
    return lag, fits


def _joint_fit(segments, cell, joints, names, dadr, kv_nom, payload, dt,
               errors: bool = True) -> list[Fitted]:
    """Armature, damping, friction per joint and (if ``payload``) the payload, from one stacked least-squares
    solve."""
    model = cell.model
    rigid = rigid_model(model)
    loaded = rigid_model(model, payload_kg=1.0) if payload else None
    nj = len(joints)
    # the three joint terms are always fitted together (each alone absorbs the others); the wanted ones are reported
    blocks = {"armature": 0, "damping": 1, "friction": 2}
    ncol = len(blocks) * nj + (1 if loaded is not None else 0)
    rows = _Rows()
    for s in segments:
        tau_rigid = inverse_torques(rigid, cell, s.q, s.qd, dt)
        tau_loaded = inverse_torques(loaded, cell, s.q, s.qd, dt) if loaded is not None else None
        acc = np.diff(s.qd, axis=0) / dt  # (n-1, dof): over each step
        qd0 = s.qd[:-1]
        for k, i in enumerate(joints):
            moving = np.abs(qd0[:, i]) > MIN_SPEED
            x = np.zeros((int(moving.sum()), ncol))
            regressors = {"armature": acc[:, i], "damping": qd0[:, i], "friction": np.sign(qd0[:, i])}
            for p, b in blocks.items():
                x[:, b * nj + k] = regressors[p][moving]
            if loaded is not None:
                x[:, -1] = (tau_loaded[:, k] - tau_rigid[:, k])[moving]
            rows.add(x, (s.tau[1:, i] - tau_rigid[:, k])[moving])
    x, y = rows.stacked()
    if len(y) < 10 * ncol:
        raise CalibrationError(f"the records move too little to identify the joint parameters ({len(y)} samples faster "
                               f"than {MIN_SPEED} rad/s); record an excitation with `cellguard excite`")
    beta, cov = _ols(x, y, errors)
    both_ways = moves_both_ways(np.concatenate([s.qd[:-1][:, joints] for s in segments]))
    out = []
    damping = beta[nj:2 * nj]
    for p, b in blocks.items():
        for k, name in enumerate(names):
            a = b * nj + k
            value, var = beta[a], cov[a, a]
            if p == "armature":  # implicit integration adds dt (kv + damping) to the effective inertia
                d = nj + k
                value = value - dt * (kv_nom[k] + damping[k])
                var = var + dt * dt * cov[d, d] - 2.0 * dt * cov[a, d]
            elif not both_ways[k]:  # fitted (each term absorbs the others) but not reported
                var = np.inf
            out.append(Fitted(p, name, float(value), float(np.sqrt(var)), float(_nominal(model, p, dadr[k]))))
    if loaded is not None:
        out.append(Fitted("payload", None, float(beta[-1]), float(np.sqrt(cov[-1, -1])), 0.0))
    return out


class _Rows:
    """Regression rows gathered stretch by stretch (each contiguous in time), stacked in that order."""

    def __init__(self):
        self.xs, self.ys = [], []

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        """Rows of one contiguous stretch: x (n, p), y (n,)."""
        self.xs.append(x)
        self.ys.append(y)

    def stacked(self) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate(self.xs), np.concatenate(self.ys)


def _ols(x: np.ndarray, y: np.ndarray, errors: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``x beta = y``: beta and its covariance (p, p), infinite variance where a column is not
    excited (``errors=False``: zeros, beta only). The covariance is White's heteroskedasticity-consistent sandwich (the joints' residuals differ
    in size), each column's variance then scaled by its effective-sample-size factor (``_ess_factor``) for
    residuals correlated in time. (A sandwich over blocks of time was tried: with a few dozen blocks
    carrying most of a column's weight it came out up to three times too small on white residuals.)"""
    scale = np.linalg.norm(x, axis=0)
    scale[scale == 0] = 1.0
    xs = x / scale
    lam, v = np.linalg.eigh(xs.T @ xs)  # columns scaled to unit norm: the normal equations are well conditioned
    good = lam > NULL_EIG * lam.max()
    pinv = (v[:, good] / lam[good]) @ v[:, good].T
    beta_s = pinv @ (xs.T @ y)  # the minimum-norm solution, unexcited directions left at zero
    if not errors:
        return beta_s / scale, np.zeros((len(scale), len(scale)))
    r = y - xs @ beta_s
    n, p = len(y), x.shape[1]
    white = pinv @ ((xs * (r * r)[:, None]).T @ xs) @ pinv * (n / max(n - p, 1))
    root = np.sqrt(np.array([_ess_factor(xs[:, c], r) for c in range(p)]))
    cov = white * np.outer(root, root)
    unexcited = (np.abs(v[:, ~good]) > 1e-6).any(axis=1) | (np.linalg.norm(x, axis=0) == 0)
    cov[unexcited, unexcited] = np.inf
    return beta_s / scale, cov / np.outer(scale, scale)


def _ess_factor(column: np.ndarray, r: np.ndarray) -> float:
    """``n / n_eff`` of one regressor's coefficient: ``1 + 2 sum_l w_l rho_r(l) rho_x(l)`` over lags up to
    ``ESS_LAGS`` (Bartlett weights ``w_l``), with ``rho_r`` the residual's and ``rho_x`` the regressor's
    (uncentred) autocorrelation over the rows the regressor acts on. 1 for white residuals; above 1 when
    residual and regressor are both correlated in time (a slow model mismatch), below when they oppose."""
    rows = column != 0
    xc, rc = column[rows], r[rows]
    xx, rr = float(xc @ xc), float(rc @ rc)
    if len(xc) <= ESS_LAGS or xx == 0 or rr == 0:
        return 1.0
    total = 1.0
    for lag in range(1, ESS_LAGS + 1):
        weight = 1.0 - lag / (ESS_LAGS + 1)
        total += 2.0 * weight * float(rc[lag:] @ rc[:-lag]) / rr * float(xc[lag:] @ xc[:-lag]) / xx
    return max(total, 0.0)


@dataclass(frozen=True)
class Fitted:
    """A fitted parameter before its interval: ``se`` its standard error (inf: not excited by the data)."""

    parameter: str
    joint: str | None
    value: float
    se: float
    nominal: float
    bias: float = 0.0  # the method's own error at this value (``method_bias``); widens the interval


def simultaneous_z(m: int) -> float:
    """Normal quantile that gives ``m`` intervals a joint coverage of ``LEVEL`` (Sidak)."""
    return float(stats.norm.isf((1.0 - LEVEL ** (1.0 / max(m, 1))) / 2.0))


def _identified(estimates: list) -> int:
    """How many of ``estimates`` (Estimate or Fitted) get an interval."""
    return sum(bool(np.isfinite(e.se)) if isinstance(e, Fitted) else e.identifiable for e in estimates)


def interval_note(estimates: list) -> str:
    """What the intervals of ``estimates`` (Estimate or Fitted) claim, in words."""
    m = _identified(estimates)
    return (f"{LEVEL:.0%} simultaneous over the {m} identified parameters (each at {LEVEL ** (1 / max(m, 1)):.2%}, "
            f"z {simultaneous_z(m):.2f}); heteroskedasticity-consistent standard errors with an effective sample "
            f"size over {ESS_LAGS} lags")


def with_intervals(estimates: list) -> list[Estimate]:
    """``estimates`` (Estimate or Fitted, in order) as Estimates, each Fitted given its simultaneous interval:
    all identified parameters of the list count towards the coverage, the delay (interval set by its search)
    included."""
    z = simultaneous_z(_identified(estimates))
    return [_estimate(e.parameter, e.joint, e.value, z * e.se + abs(e.bias), e.nominal) if isinstance(e, Fitted) else e
            for e in estimates]


def _estimate(parameter: str, joint: str | None, value: float, half: float, nominal: float) -> Estimate:
    if not np.isfinite(half):
        return Estimate(parameter, joint, None, UNITS[parameter], nominal, None, None)
    return Estimate(parameter, joint, value, UNITS[parameter], nominal, value - half, value + half)
