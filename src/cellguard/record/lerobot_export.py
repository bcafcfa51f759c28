"""A record's cycles as a LeRobotDataset v3, for fine-tuning a policy on this robot's own data.

One completed cycle is one episode: a cycle the run's stop cut short, or whose start or end the record lost (its
begin or end marker, or the ticks at either edge), is left out and named. Frames come from the record's continuous
decimated tick stream (every ``round(servo rate / decimated_hz)``-th servo tick, at least every one: 50 Hz at 1 kHz,
30 Hz at 30 Hz), every ``k``-th tick of it for a whole ``fps`` (LeRobot's fps is an integer);
the full-rate windows around events are not used, so every episode has the same frame period.
Per frame: ``observation.state`` the measured joint positions, ``observation.velocity`` and
``observation.effort`` the measured velocities and efforts, ``action`` the setpoint actually
sent (after the envelope, not what the policy asked), ``observation.environment_state`` the
latest camera and fixture readings the policy was shown (held between requests), all SI and
named by joint. The cells record no images, so the dataset has no video features.

The layout is what lerobot 0.4 (``CODEBASE_VERSION = "v3.0"``) writes and reads: ``meta/info.json``,
``meta/stats.json``, ``meta/tasks.parquet``, ``meta/episodes/chunk-000/file-000.parquet`` and
``data/chunk-000/file-000.parquet``; written with pyarrow alone, so lerobot is not needed here.
``LeRobotDataset(repo_id, root=DATASET)`` loads it without the hub.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from cellguard.control.events import EventKind
from cellguard.errors import RecordError
from cellguard.output import refuse_filled_folder
from cellguard.record import folder_lock, staged
from cellguard.record.reader import CycleRecord, Record
from cellguard.record.writer import decimation_stride

CODEBASE_VERSION = "v3.0"
DATA_FILE = "data/chunk-000/file-000.parquet"
EPISODES_FILE = "meta/episodes/chunk-000/file-000.parquet"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
MAX_FPS = 1000  # [Hz] the fastest frame rate a dataset is written at (a servo rate's)
STEP_TOLERANCE_NS = 1000  # a frame step this close to the period is the period; a missing frame is 1/fps off
# [ms] the servo periods a refused record's message looks through for rates that export: whole milliseconds, as the
# simulated cells' 1 ms physics steps serve them (sim-server --rate-hz)
SUGGESTED_PERIODS_MS = range(1, 21)
STAGING_SUFFIX = ".partial"  # of the folder beside -o that a run writes into: .NAME.XXXXXXXX.partial
DATASET_PARTS = ("data", "meta")  # moved into -o in this order
INDEX_FEATURES = ("timestamp", "frame_index", "episode_index", "index", "task_index")
# the events after which the run stops (EventKind.ends_run): a cycle one falls in was cut short, not completed
RUN_STOPS = frozenset(kind for kind in EventKind if kind.ends_run)
_TICK_FEATURES = {"observation.state": "q_meas", "observation.velocity": "qd_meas",
                  "observation.effort": "effort", "action": "q_cmd"}


@dataclass(frozen=True)
class LeRobotExport:
    """What was written: episodes (cycle numbers), frames, and the cycles left out with why."""

    path: str
    fps: int
    episodes: tuple[int, ...]  # the record's cycle number of each episode, in order
    frames: int
    skipped: tuple[str, ...]


def export_lerobot(rec: Record, output: Path, fps: int | None = None, task: str | None = None,
                   success_only: bool = False, robot_type: str | None = None) -> LeRobotExport:
    """Write the completed cycles of ``rec`` into the new folder ``output`` as a LeRobotDataset v3, at ``fps``
    (default: the record's decimated rate, 50 Hz at most servo rates, 30 Hz for a 30 Hz robot)."""
    if task is not None and not task.isprintable():  # one line in tasks.parquet, as every other text cellguard takes
        raise RecordError(f"--task: {task!r} holds control characters; give the task as one line of text")
    if task is not None and not task.strip():  # "" became the default unasked, "  " an empty instruction
        raise RecordError(f"--task: {task!r} is blank; give the task as one line of text, or leave --task out")
    output = Path(output).resolve()  # "." and ".." have no name to put the staging folder beside
    context = rec.context
    stride, fps = _stride(context, fps)
    task = task or (context.get("cell") or "cycle").replace("-", " ")
    measurements = _measurements(rec)
    columns: dict[str, list[np.ndarray]] = {}
    episodes, kept = [], []
    cycles, stops = list(rec.cycles()), [(e.t_ns, e.kind) for e in rec.events() if e.kind in RUN_STOPS]
    # marked but not ended (its end marker lost in a damaged chunk or malformed, or the run was killed in it): no
    # outcome, no end, so no episode; named, not dropped unsaid. The last one marked in a record still being written
    # is running: its end was not lost, it is yet to come
    marked = set(rec.cycle_spans())
    running = max(marked) if rec.writing and marked else None
    skipped = [(n, f"still running (the record is still being written by {rec.writing})" if n == running
                else "its end was lost") for n in sorted(marked - {c.cycle for c in cycles})]
    joints: tuple[str, ...] = ()
    for cycle in cycles:
        if success_only and not cycle.success:
            continue
        ticks = rec.ticks(cycle=cycle.cycle, rate="decimated")
        t = ticks.t_ns[::stride]
        why = _cut_short(cycle, stops) or _incomplete(cycle, ticks.t_ns, t, fps, stride)
        if why:
            skipped.append((cycle.cycle, why))
            continue
        frames = {name: getattr(ticks, field)[::stride] for name, field in _TICK_FEATURES.items()}
        if measurements:
            if cycle.cycle not in measurements:  # lost (a damaged record): its frames were NaN, and so its stats
                skipped.append((cycle.cycle, "no camera or fixture readings recorded in it"))
                continue
            frames["observation.environment_state"] = _held(measurements[cycle.cycle], t)
        unfit = _not_float32(frames)
        if unfit:
            skipped.append((cycle.cycle, unfit))
            continue
        joints = ticks.joints
        n, start = len(t), sum(len(c) for c in columns.get("index", []))
        frames |= {"timestamp": np.arange(n) / fps, "frame_index": np.arange(n), "episode_index": np.full(n, len(kept)),
                   "index": start + np.arange(n), "task_index": np.zeros(n, np.int64)}
        for name, values in frames.items():
            columns.setdefault(name, []).append(values)
        episodes.append({"episode_index": len(kept), "tasks": [task], "length": n, "data/chunk_index": 0,
                         "data/file_index": 0, "dataset_from_index": start, "dataset_to_index": start + n,
                         **{f"stats/{k}/{s}": v for k, vals in frames.items() for s, v in _stats(vals).items()},
                         "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                         "cellguard/cycle": cycle.cycle, "cellguard/phase": cycle.phase,
                         "cellguard/success": cycle.success, "cellguard/t_start_ns": cycle.t_start_ns})
        kept.append(cycle.cycle)
    skipped = [f"cycle {n}: {why}" for n, why in sorted(skipped, key=lambda item: item[0])]
    if not kept:
        raise RecordError(f"{rec.file}: no cycle to export" + (f" ({'; '.join(skipped)})" if skipped else ""))
    data = {k: np.concatenate(v) for k, v in columns.items()}
    features = _features(data, joints, measurements)
    made = not output.exists()
    staging = _prepare(output)
    robot_type = robot_type or (context.get("embodiment") or {}).get("robot")
    lock, refused = None, False
    try:
        # while this run lives (the next export clears it once it was killed); made just now: no hold to wait out
        lock = folder_lock.hold(staging, "-o", wait_s=0)
        _write_dataset(staging, data, features, episodes, kept, task, robot_type, fps)
        staged.note_files(staging)  # a rerun after a kill between the moves takes out what they moved
        # into the empty folder _prepare checked or made, which stays the same folder (it may be a shell's
        # current folder); meta/ last: a dataset without meta/info.json is not one to LeRobot
        for part in DATASET_PARTS:
            (staging / part).rename(output / part)
    except BaseException as exc:  # a full disk, Ctrl-C, SIGTERM: nothing of this run's is left in -o
        # a file not its own appeared there: its note must stay
        refused = not staged.take_back(staging, output, _is_staging(output))
        if made:
            with contextlib.suppress(OSError):
                output.rmdir()  # only if empty
        if isinstance(exc, OSError):  # named as given: the staging folder is this run's own (kept: the rerun names it)
            raise RecordError(f"-o {output}: cannot write ({exc.strerror or exc})") from None
        raise
    finally:
        if not refused:  # this run's own folder; empty once its parts moved
            shutil.rmtree(staging, ignore_errors=True)
        folder_lock.release(lock)
    return LeRobotExport(str(output), fps, tuple(kept), len(data["index"]), tuple(skipped))


def _write_dataset(output: Path, data: dict, features: dict, episodes: list, kept: list, task: str,
                   robot_type: str | None, fps: int) -> None:
    for sub in ("data/chunk-000", "meta/episodes/chunk-000"):
        (output / sub).mkdir(parents=True, exist_ok=True)
    _write_parquet(output / DATA_FILE, _data_table(data, features))
    _write_parquet(output / EPISODES_FILE, pa.Table.from_pylist(episodes))
    _write_parquet(output / "meta/tasks.parquet", _tasks_table([task]))
    info = {"codebase_version": CODEBASE_VERSION, "robot_type": robot_type,
            "total_episodes": len(kept), "total_frames": len(data["index"]), "total_tasks": 1, "chunks_size": 1000,
            "data_files_size_in_mb": 100, "video_files_size_in_mb": 200, "fps": fps,
            "splits": {"train": f"0:{len(kept)}"},
            "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
            "video_path": None, "features": features}
    _write_json(output / "meta/info.json", info)
    _write_json(output / "meta/stats.json", {k: _stats(v) for k, v in data.items()})


def evenly_spaced(t_ns: np.ndarray, fps: float) -> bool:
    """Whether frames at ``t_ns`` [ns] follow each other at ``fps`` with none missing: each step within
    ``STEP_TOLERANCE_NS`` of the period (the clock's steps round to the nanosecond: an exact test dropped 3 of
    the demo's 80 cycles as "gaps" for steps of 20,000,001 ns)."""
    return bool(np.all(_is_period(np.diff(t_ns), fps)))


def _incomplete(cycle: CycleRecord, ticks_ns: np.ndarray, t_ns: np.ndarray, fps: int, stride: int) -> str:
    """Why a cycle's decimated ``ticks_ns`` and its frames ``t_ns`` (every ``stride``-th of them) are not the whole
    cycle ("" if they are): a gap inside, or more than one tick missing between its start or end and its first or last
    tick (a damaged chunk at a cycle's edge cut the episode short unnamed, or started it 120 ms late at timestamp 0)."""
    tick_ns = 1e9 / (fps * stride)
    if len(t_ns) < 2:
        return "no ticks"
    if not evenly_spaced(t_ns, fps):
        return "gap in the decimated ticks"
    if ticks_ns[0] - cycle.t_start_ns > tick_ns + STEP_TOLERANCE_NS:
        return "ticks lost at its start"
    if cycle.t_end_ns - ticks_ns[-1] > tick_ns + STEP_TOLERANCE_NS:
        return "ticks lost at its end"
    return ""


def _cut_short(cycle: CycleRecord, stops: list[tuple[int, str]]) -> str:
    """Why ``cycle`` is not a completed one ("" if it is): the run's stop came while it ran, so it ended at standstill
    after braking, not at its task's end (a failed task is data and stays; ``--success-only`` leaves it out)."""
    kinds = [kind for t, kind in stops if cycle.t_start_ns <= t <= cycle.t_end_ns]
    return f"cut short by {kinds[0]}" if kinds else ""


def _is_period(step_ns, fps: float) -> np.ndarray:
    """Whether each step [ns] is the frame period at ``fps``, to ``STEP_TOLERANCE_NS``."""
    return np.abs(np.asarray(step_ns) - 1e9 / fps) <= STEP_TOLERANCE_NS


def _stride(context: dict, fps: int | None) -> tuple[int, int]:
    """Every how many decimated ticks one frame is taken, and the fps (None: the stream's own, if whole; a fixed
    default of 50 refused every 30 Hz record); RecordError unless fps divides the stream's rate.

    A stream no whole fps divides (14 of the 20 rates sim-server serves up to 20 ms, e.g. 62.5 Hz) is refused, naming
    the servo rates that export: lerobot 0.4 takes fps as an int (``create_empty_dataset_info(fps: int)`` and
    ``LeRobotDatasetMetadata.fps -> int`` in ``lerobot/datasets/utils.py`` and ``lerobot_dataset.py``; its video
    writer's time base is ``Fraction(1, fps)``) and a frame's timestamp as ``frame_index / fps``, so frames on another
    grid would be values the robot never measured nor was sent."""
    dt_ns = context.get("servo_period_ns")
    hz = (context.get("record") or {}).get("decimated_hz")
    if not dt_ns or not hz:
        raise RecordError("record context: servo_period_ns or record.decimated_hz is missing; "
                          "cannot tell the tick rate")
    stride = decimation_stride(dt_ns, hz)
    rates, rate = _whole_rates(stride * dt_ns), 1e9 / (stride * dt_ns)
    if not rates:
        raise _no_whole_rate(dt_ns, stride, hz)
    fps = rates[0] if fps is None else fps
    if fps not in rates:
        raise RecordError(f"--fps: {fps} must divide the record's continuous tick rate {rate:g} Hz "
                          f"(e.g. {', '.join(map(str, rates[:3]))})")
    return round(rate / fps), fps


def _whole_rates(period_ns: int) -> list[int]:
    """The whole frame rates [Hz], at most ``MAX_FPS``, that every k-th tick of a stream ``period_ns`` apart gives,
    fastest first (a tick period is whole nanoseconds: 30 Hz is 33,333,333 ns, its frames within
    ``STEP_TOLERANCE_NS`` of 1/30 s). Tried per frame rate, not per k: a context stating a 1 ns tick made k run
    to 10^9."""
    rate = 1e9 / period_ns
    candidates = ((max(1, round(rate / fps)), fps) for fps in range(min(round(rate), MAX_FPS), 0, -1))
    return [fps for k, fps in candidates if _is_period(k * period_ns, fps)]


def _no_whole_rate(dt_ns: int, stride: int, decimated_hz: float) -> RecordError:
    """The refusal of a record whose continuous stream no whole fps divides: its rate, and the servo rates that do."""
    servo = "its servo rate" if stride == 1 else f"1 in {stride} ticks of its {1e9 / dt_ns:g} Hz servo"
    working = ", ".join(f"{r:g}" for r in _exporting_servo_rates(decimated_hz))
    # other servo rates may export where none of these does (at 7 Hz, a 700 Hz servo at 7 fps): said of these only
    remedy = (f"Records at servo rates of {working} Hz export (of those whose period is whole milliseconds, up to "
              f"{SUGGESTED_PERIODS_MS[-1]} ms)" if working else
              f"None of the whole-millisecond servo periods up to {SUGGESTED_PERIODS_MS[-1]} ms exports at "
              f"record.decimated_hz {decimated_hz:g}" + (" (a whole fps is 1 Hz at least)" if decimated_hz < 1 else ""))
    return RecordError(f"--fps: no whole frame rate divides the record's continuous tick rate "
                       f"{1e9 / (stride * dt_ns):g} Hz ({servo}); a LeRobotDataset's fps is a whole number. {remedy}")


def _exporting_servo_rates(decimated_hz: float) -> list[float]:
    """The servo rates [Hz] of ``SUGGESTED_PERIODS_MS`` whose continuous stream at ``decimated_hz`` has a whole fps."""
    return [1e3 / ms for ms in SUGGESTED_PERIODS_MS
            if _whole_rates(decimation_stride(ms * 1_000_000, decimated_hz) * ms * 1_000_000)]


def _measurements(rec: Record) -> dict[int, tuple[np.ndarray, np.ndarray, tuple[str, ...]]]:
    """Per cycle: request times (n,), readings (n, m) and their names (one layout: the reader skips others)."""
    rows: dict[int, list] = {}
    for m in rec.measurements():
        rows.setdefault(m.cycle, []).append(m)
    return {cycle: (np.array([m.t_ns for m in items], dtype=np.int64),
                    np.array([m.values for m in items], dtype=np.float64), items[0].names)
            for cycle, items in rows.items()}


def _held(readings: tuple[np.ndarray, np.ndarray, tuple[str, ...]], t: np.ndarray) -> np.ndarray:
    """The latest of a cycle's ``readings`` at or before each frame time (the first one before any was taken)."""
    times, values, _ = readings
    return values[np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1)]


def _not_float32(frames: dict[str, np.ndarray]) -> str:
    """What of a cycle's ``frames`` the dataset cannot hold ("" for none): a feature with NaN, an infinity or a value
    beyond float32 (the data's type, inf once cast); LeRobot normalises with stats over them, and NaN made
    meta/stats.json invalid JSON."""
    for name, values in frames.items():
        with np.errstate(over="ignore"):
            bad = ~np.isfinite(np.asarray(values, dtype=np.float32)).reshape(len(values), -1).all(axis=1)
        if bad.any():
            return f"{name} is NaN, infinite or beyond float32 in {int(bad.sum())} of its {len(values)} frames"
    return ""


def _features(data: dict, joints: tuple[str, ...], measurements: dict) -> dict:
    features = {}
    for name in (*_TICK_FEATURES, "observation.environment_state"):
        if name in data:
            names = list(joints) if name in _TICK_FEATURES else list(next(iter(measurements.values()))[2])
            features[name] = {"dtype": "float32", "shape": [data[name].shape[1]], "names": names}
    features["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
    for name in INDEX_FEATURES[1:]:
        features[name] = {"dtype": "int64", "shape": [1], "names": None}
    return features


def _data_table(data: dict, features: dict) -> pa.Table:
    arrays = {}
    for name, spec in features.items():
        values = data[name]
        if spec["dtype"] == "float32" and spec["shape"] != [1]:
            flat = pa.array(values.astype(np.float32).reshape(-1))
            arrays[name] = pa.FixedSizeListArray.from_arrays(flat, spec["shape"][0])
        else:
            arrays[name] = pa.array(values.astype(spec["dtype"]))
    return pa.table(arrays)


def _tasks_table(tasks: list[str]) -> pa.Table:
    """``task_index`` with the task strings as the pandas index, as lerobot reads it (``pd.read_parquet``)."""
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()),
                      "__index_level_0__": pa.array(tasks, pa.string())})
    pandas_meta = {"index_columns": ["__index_level_0__"], "column_indexes": [], "columns": [
        {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
         "metadata": None},
        {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object",
         "metadata": None}], "attributes": {}, "creator": {"library": "pyarrow", "version": pa.__version__}}
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def _stats(values: np.ndarray) -> dict[str, list]:
    """min, max, mean, std, count and the quantiles lerobot normalises with, per dimension."""
    v = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    q = np.quantile(v, QUANTILES, axis=0)
    return {"min": v.min(0).tolist(), "max": v.max(0).tolist(), "mean": v.mean(0).tolist(), "std": v.std(0).tolist(),
            "count": [len(v)], **{f"q{round(p * 100):02d}": q[i].tolist() for i, p in enumerate(QUANTILES)}}


def _prepare(output: Path) -> Path:
    """Check or make the empty folder ``output`` (``output.resolve()``), once what a killed export had moved into it is
    taken out; a new folder in ``_staging_home``, unique to this run, to write into."""
    refuse_filled_folder(output, "-o", _clear_stale_staging(output))
    try:
        output.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=_staging_prefix(output), suffix=STAGING_SUFFIX, dir=_staging_home(output)))
    except OSError as exc:
        raise RecordError(f"-o {output}: cannot write ({exc.strerror})") from None


def _staging_home(output: Path) -> Path:
    """Where the staging folder of an export into ``output`` goes: beside it, or in it where ``output`` is a mount point
    (a folder on another filesystem than its parent's), so that its parts are renamed into place on one filesystem
    (from beside a mount point the moves failed: "Invalid cross-device link")."""
    try:
        if output.is_dir() and output.stat().st_dev != output.parent.stat().st_dev:
            return output
    except OSError:
        pass  # _prepare's write says why
    return output.parent


def _staging_prefix(output: Path) -> str:
    return f".{output.name}."


def _is_staging(output: Path) -> Callable[[Path], bool]:
    """Whether a path is the staging folder of an export into ``output`` (``mkdtemp``'s name, a real folder)."""
    mine = re.compile(re.escape(_staging_prefix(output)) + r"[a-z0-9_]{8}" + re.escape(STAGING_SUFFIX))
    return lambda path: bool(mine.fullmatch(path.name)) and path.is_dir() and not path.is_symlink()


def _clear_stale_staging(output: Path) -> str:
    """Remove the staging folders of exports into ``output`` killed before their clean-up (SIGKILL: nothing holds
    their lock; each stayed for good), and the parts of the dataset one had moved into ``output`` before it was
    killed where it holds nothing else (``staged``; the rerun was refused as "not empty"); RecordError if an export
    into ``output`` is still writing. Returns what to say of the ones kept (``staged.clear_killed``)."""
    staging = _is_staging(output)
    try:
        leftovers = [p for p in _staging_home(output).iterdir() if staging(p)]
    except OSError:
        return ""  # the folder's own write says why it cannot be read
    return staged.clear_killed(leftovers, output, f"-o {output}: another export is writing there", staging)


def _write_parquet(path: Path, table: pa.Table) -> None:
    """Through a Python file: pyarrow's own path handling takes UTF-8 only (a folder name that is not UTF-8 ended
    in a UnicodeEncodeError traceback). OSError: the caller names -o as given."""
    with open(path, "wb") as f:
        pq.write_table(table, f)


def _write_json(path: Path, doc: dict) -> None:
    """Strict JSON: a number that is not finite (none once ``_not_float32`` kept its cycle out) is refused, never a file
    LeRobot reads as NaN."""
    try:
        text = json.dumps(doc, indent=4, allow_nan=False)
    except ValueError as exc:
        raise RecordError(f"meta/{path.name}: {exc}; nothing written") from None
    path.write_text(text)
