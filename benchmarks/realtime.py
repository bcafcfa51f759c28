"""The real-time loop against ``cellguard sim-server``: period error, overruns, inference latency.

For each servo rate (1 kHz, 200 Hz), policy and inference worker (thread, process), a sim-server
is started in its own process at that rate and one scenario runs for ``--seconds`` of wall time:

- ``onnx100``: an ONNX model whose heavy branch (a chain of 256x256 matmuls on an input-dependent
  matrix) is sized at start to take about 100 ms per call; its chunk sways the shoulder.
- ``python``: a pure-Python CPU-bound policy (about 50 ms of interpreter work per call, holding
  the GIL) with the same chunk.
- ``sway``: the same chunk with no work at all: the loop, the bridge and the server alone.

``--recording on,off``: ``off`` runs the same loop with no record, so that what the recorder adds
shows beside it. Comparing ``sway`` without a record, ``sway`` with one, and the heavy policies
with one, each against the machine's floor, tells which ticks inference or recording made late.

Prints one JSON document: the host's load and reference costs measured in the same run (one
``mj_step``, one ruckig update); per rate, the machine's own floor (the loop's wall clock and
real-time thread pacing ticks that do nothing: a late tick there is the host's, not cellguard's);
and per run: period error p50/p99/max [us], compute time, overruns, ticks two or more periods
late, the recorder's cost on the servo thread per tick [us] (calls over 200 us, and why: on the CPU,
waited, preempted, unexplained; the floor times a 1 us row copy the same way), the scheduler the servo thread got
(``fifo:N`` where SCHED_FIFO is permitted, else ``other``), inference latency [ms], packets
lost, link events, the recorder queue high-water mark [ticks; it includes up to one batch, 100 ticks
at 1 kHz] and the writer's lag beyond it, the CPU time a hypervisor
took for other guests meanwhile (``host_steal_ms``, Linux guests; a real-time thread cannot
win that back), and, where the sim-server ended during the run, its last line (``server_ended``).

``--cycle-seconds S`` splits each run into time cycles of S seconds (default: one cycle of the whole run), so the
figure includes cycle ends: the cycles run in one stretch of ticks, a cycle's end is work inside the period grid
(``between_cycles_ms``: its wall time; a longer one shows as compute time, late ticks and overruns), as is the
retreat's brake after the last cycle (its plan from motion: late ticks); the retreat's way home, checked at rest,
follows a pause (``pauses_between_stretches``). ``inference_ms`` covers every cycle (``wall_ms_p99``: the worst
cycle's).

Usage: ``python benchmarks/realtime.py --seconds 300`` (the figure), ``--seconds 20`` (CI),
``--seconds 300 --cycle-seconds 10`` (30 cycle ends among the ticks).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from functools import partial
from pathlib import Path

import numpy as np

from cellguard.errors import CellguardError, ConfigError
from cellguard.policy.chunk import ActionChunk
from cellguard.record.ring import TickRing
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run, run_scenario
from cellguard.runtime.clock import WallClock
from cellguard.runtime.servo_thread import PRIORITY, ServoThread
from cellguard.runtime.sim_server import served_substeps
from cellguard.scenario import parse_scenario

HOME = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])
JOINTS = "shoulder_pan,shoulder_lift,elbow,wrist_flex,wrist_roll,gripper"
HORIZON, DT_S = 50, 0.02  # a 1 s chunk, like ACT / pi0 chunks of 50
CELL = "arm-pick-place"
MAX_CYCLES = 100_000  # the most time cycles --cycle-seconds may split a run into
WEEK_S = 7 * 24 * 3600  # the longest --seconds (the sim-server's own bound on --duration-s)
READ_AFTER_END_S = 5.0  # how long its output is read once it has ended (a child of its own could hold the pipe)
START_S = 60.0  # [s] for its start line: 1.1 s measured on a quiet 2-core host, up to 24 s with six busy processes


def sway(t_s: np.ndarray) -> np.ndarray:
    """Chunk (H, 6) swaying the shoulder around home from episode time ``t_s``."""
    steps = t_s + np.arange(HORIZON) * DT_S
    actions = np.broadcast_to(HOME, (HORIZON, 6)).copy()
    actions[:, 0] = 0.1 * np.sin(np.pi * steps)
    return actions


class PythonPolicy:
    """Pure-Python work of ``work`` loop iterations per call (holds the GIL), then a sway chunk."""

    source = "bench:python"

    def __init__(self, work: int):
        self.work = work
        self.reset()

    def reset(self) -> None:
        self._t0 = None

    def content_hash(self) -> str:
        return f"python-{self.work}"

    def infer(self, observation) -> ActionChunk:
        acc = 0
        for i in range(self.work):
            acc = (acc + i * i) % 7919
        if self._t0 is None:
            self._t0 = observation.t_ns
        return ActionChunk(sway((observation.t_ns - self._t0) * 1e-9), observation.t_ns, round(DT_S * 1e9))


def python_work_for(ms: float) -> int:
    n = 200_000
    t = time.perf_counter()
    PythonPolicy(n).infer(type("O", (), {"t_ns": 0})())
    return max(1000, int(n * ms * 1e-3 / (time.perf_counter() - t)))


def onnx_model(path: Path, target_ms: float) -> Path:
    """An ONNX policy taking about ``target_ms`` per call on this host (layers sized by a trial run)."""
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper

    def build(layers: int) -> bytes:
        n = 256
        rng = np.random.default_rng(0)
        inits = [numpy_helper.from_array(rng.normal(0, 1 / 16, (6, n)).astype(np.float32), "P"),
                 numpy_helper.from_array((rng.normal(0, 1 / 16, (n, n))).astype(np.float32), "W"),
                 numpy_helper.from_array(np.zeros(1, np.float32), "zero"),
                 numpy_helper.from_array((np.arange(HORIZON) * DT_S).astype(np.float32)[None], "steps"),
                 numpy_helper.from_array(np.float32([np.pi]), "pi"), numpy_helper.from_array(np.float32([0.1]), "amp"),
                 numpy_helper.from_array(np.broadcast_to(HOME, (HORIZON, 6)).astype(np.float32), "home"),
                 numpy_helper.from_array(np.eye(6, dtype=np.float32)[:1], "e0"),
                 numpy_helper.from_array(np.array([1, HORIZON, 6], np.int64), "shape"),
                 numpy_helper.from_array(np.array([HORIZON, 1], np.int64), "col")]
        nodes = [helper.make_node("MatMul", ["state", "P"], ["x"]), helper.make_node("Transpose", ["x"], ["xt"]),
                 helper.make_node("MatMul", ["xt", "x"], ["y0"])]
        for k in range(layers):
            nodes += [helper.make_node("MatMul", [f"y{k}", "W"], [f"m{k}"]), helper.make_node("Tanh", [f"m{k}"], [f"y{k + 1}"])]
        nodes += [helper.make_node("ReduceSum", [f"y{layers}"], ["s"], keepdims=0),
                  helper.make_node("Mul", ["s", "zero"], ["s0"]),
                  helper.make_node("Add", ["time_s", "steps"], ["tt"]), helper.make_node("Mul", ["tt", "pi"], ["ph"]),
                  helper.make_node("Sin", ["ph"], ["sn"]), helper.make_node("Mul", ["sn", "amp"], ["sw"]),
                  helper.make_node("Reshape", ["sw", "col"], ["swc"]), helper.make_node("MatMul", ["swc", "e0"], ["d"]),
                  helper.make_node("Add", ["home", "d"], ["a0"]), helper.make_node("Add", ["a0", "s0"], ["a1"]),
                  helper.make_node("Reshape", ["a1", "shape"], ["actions"])]
        graph = helper.make_graph(nodes, "bench", [helper.make_tensor_value_info("state", TensorProto.FLOAT, [1, 6]),
                                                   helper.make_tensor_value_info("time_s", TensorProto.FLOAT, [1, 1])],
                                  [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, HORIZON, 6])], inits)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
        model.ir_version = 8
        for key, value in (("cellguard.action_names", JOINTS), ("cellguard.dt_s", str(DT_S))):
            entry = model.metadata_props.add()
            entry.key, entry.value = key, value
        onnx.checker.check_model(model)
        return model.SerializeToString()

    def per_call_ms(data: bytes) -> float:
        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        session = ort.InferenceSession(data, options, providers=["CPUExecutionProvider"])
        feed = {"state": np.ones((1, 6), np.float32), "time_s": np.zeros((1, 1), np.float32)}
        session.run(None, feed)
        t = time.perf_counter()
        for _ in range(3):
            session.run(None, feed)
        return (time.perf_counter() - t) / 3 * 1e3

    # sized as the loop runs it: the inference thread sits one real-time priority below the servo thread
    with ServoThread(priority=PRIORITY - 1):
        trial = per_call_ms(build(8)) / 8
    path.write_bytes(build(max(1, round(target_ms / trial))))
    return path


def steal_ms() -> float | None:
    """CPU time the hypervisor gave to other guests so far, all CPUs [ms] (/proc/stat's ``steal``);
    None where the host does not say. A late tick in a run with steal may be the host's."""
    try:
        with open("/proc/stat") as stat:
            fields = stat.readline().split()
        return int(fields[8]) * 1e3 / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def stolen(before: float | None) -> float | None:
    after = steal_ms()
    return None if before is None or after is None else round(after - before, 1)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_run(rate_hz: float, policy: str, worker: str, seconds: float, onnx_path: Path, work: int, out: Path,
            recording: bool = True, cycle_seconds: float | None = None) -> dict:
    """One scenario of ``seconds`` against a sim-server at ``rate_hz``: cycles of ``cycle_seconds`` (None: one)."""
    cycle_s = seconds if cycle_seconds is None else cycle_seconds
    port = free_port()
    server = SimServerProcess([sys.executable, "-c", "from cellguard.cli import app; app()", "sim-server", CELL,
                               "--port", str(port), "--rate-hz", str(rate_hz)])
    try:
        refused = server.serving()
        if refused:
            return {"rate_hz": rate_hz, "policy": policy, "worker": worker, "refused": refused}
        spec = {"cell": CELL, "robot": f"sim-server:udp://127.0.0.1:{port}",
                "policy": f"onnx:{onnx_path}" if policy == "onnx100" else "scripted",
                "acceptance_cycles": max(1, round(seconds / cycle_s)), "production_cycles": 0,
                "cycle": {"source": "time", "seconds": cycle_s},
                # a new chunk is asked for at half the 1 s horizon: chunks come every ~0.5 s + latency
                "guard": {"watchdog_s": 1.0},
                "realtime": {"inference": worker, "overrun_budget": 1_000_000, "stale_s": 1.0, "read_timeout_s": 0.5,
                             "drop_budget": 1_000_000}}
        factory = {"python": partial(PythonPolicy, work), "sway": partial(PythonPolicy, 0)}.get(policy)
        steal_before = steal_ms()
        try:
            summary = (run_scenario(parse_scenario(spec), out, policy_factory=factory) if recording
                       else _unrecorded(parse_scenario(spec), factory))
        except CellguardError as exc:  # e.g. a start-up check refused: reported, the other runs go on
            return {"rate_hz": rate_hz, "policy": policy, "worker": worker, "refused": str(exc),
                    **server.ended_during_run()}
        ended = server.ended_during_run()
    finally:
        server.stop()
    events = Counter(e["kind"] for e in summary["events"])
    return {"rate_hz": rate_hz, "policy": policy, "worker": worker, "recording": recording, "seconds": seconds,
            "cycles": len(summary["cycles"]), "cycle_seconds": cycle_s, **summary["timing"],
            "inference_ms": inference_over(summary["cycles"]), "events": dict(events),
            "stopped": summary.get("stopped"), **ended, "host_steal_ms": stolen(steal_before)}


def inference_over(cycles: list[dict]) -> dict | None:
    """The cycles' inference latencies as one: chunks, their mean, the worst cycle's p99, the longest [ms]."""
    each = [c["inference"] for c in cycles if c.get("inference", {}).get("chunks")]
    if not each:
        return cycles[0].get("inference") if cycles else None
    chunks = sum(i["chunks"] for i in each)
    return {"chunks": chunks, "wall_ms_mean": sum(i["wall_ms_mean"] * i["chunks"] for i in each) / chunks,
            "wall_ms_p99": max(i["wall_ms_p99"] for i in each), "wall_ms_max": max(i["wall_ms_max"] for i in each)}


class SimServerProcess:
    """A sim-server ``command`` (``cellguard sim-server ...``) in its own process. Its output (stdout and stderr as
    one stream) is read to its end on a thread, its last line kept: read only up to the start line, the pipe filled
    (64 KiB, about three minutes of its once-a-second notes of stray packets) and the server blocked mid-tick on its
    next note, a stalled robot that the run's figures blamed on the loop."""

    def __init__(self, command: list[str]):
        self.command = command
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                        errors="replace", env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self._said = ""  # its last line (not blank) other than the start line
        self._serving, self._settled = threading.Event(), threading.Event()  # settled: serving, or its output ended
        self._reader = threading.Thread(target=self._read, name="sim-server output", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        with self.process.stdout as output:
            for line in output:
                if not self._serving.is_set() and line.startswith("sim-server "):
                    self._serving.set()
                    self._settled.set()
                elif line.strip():
                    self._said = line.strip()
        self._settled.set()

    def serving(self, within_s: float = START_S) -> str | None:
        """None once the server says it serves; else why it ended in its own last line (its refusal: read as the
        run's, the client's "does not answer" hid why), or, killed then, that it said nothing of serving within
        ``within_s`` (waited on for ever, a server hung before its start line hung the benchmark)."""
        if not self._settled.wait(within_s):
            self.stop()
            said = f" (its last line: {self._said})" if self._said else ""
            return f"sim-server did not say it serves within {within_s:g} s, killed: {shlex.join(self.command)}{said}"
        return None if self._serving.is_set() else self._ended(self.process.wait())

    def ended_during_run(self) -> dict:
        """``{"server_ended": why}`` if the server has ended (in its own last line; the client saw only a silent
        robot), else {}."""
        code = self.process.poll()
        return {} if code is None else {"server_ended": self._ended(code)}

    def _ended(self, code: int) -> str:
        self._reader.join(READ_AFTER_END_S)  # its last line, once the pipe is read to its end
        return f"sim-server ended (exit code {code}): {self._said or 'nothing said'}"

    def stop(self) -> None:
        self.process.kill()
        self.process.wait()
        self._reader.join(READ_AFTER_END_S)


def _unrecorded(scenario, factory) -> dict:
    """The scenario's cycles on the same loop with no record; its summary."""
    run = Run(scenario, policy_factory=factory)
    try:
        run.run_cycles()
    finally:
        run.close()
    return run.summary()


def machine_floor(rate_hz: float, seconds: float) -> dict:
    """The loop's pacing alone: the same wall clock and real-time servo thread, and per tick only one
    row copied into a private pre-trigger ring (the recorder's own step on the servo thread), timed as
    the loop times the recorder: what the host alone does to a call of about 1 µs (``ring_row_copy_us``)."""
    clock = WallClock(round(1e9 / rate_hz))
    ring, row = TickRing(6, 1000), np.zeros(6)
    timing, slow_before, perf_ns = clock.timing, clock.timing.recorder_slow.before, time.perf_counter_ns
    steal_before = steal_ms()
    clock.start()
    with clock.ticking():
        for k in range(round(seconds * rate_hz)):
            usage, began = slow_before(), perf_ns()
            ring.add(k, 0, row, row, row, row, row, row)
            timing.recorder(perf_ns() - began, usage)
            clock.advance()
    summary = clock.timing.summary()
    summary["ring_row_copy_us"] = summary.pop("recorder_tick_us")
    return {"rate_hz": rate_hz, "seconds": seconds, "scheduler": clock.scheduler, **summary,
            "host_steal_ms": stolen(steal_before)}


def reference_costs() -> dict:
    """One mj_step of the arm cell and one ruckig update (the guard benchmark's, 6 DoF) [us], measured now."""
    import mujoco

    from cellguard.bench.guard import RuckigProbe

    cell = make_cell(CELL)
    t = time.perf_counter()
    for _ in range(2000):
        mujoco.mj_step(cell.model, cell.data)
    step_us = (time.perf_counter() - t) / 2000 * 1e6
    probe = RuckigProbe(cell.profile.dof)
    probe.sample(2000)
    return {"mj_step_us": round(step_us, 2), "ruckig_update_us": round(probe.median_us(), 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="wall time per run (300 for the real figure)")
    parser.add_argument("--rates", default="1000,200", help="servo rates [Hz], comma-separated")
    parser.add_argument("--policies", default="onnx100,python")
    parser.add_argument("--workers", default="thread,process")
    parser.add_argument("--recording", default="on", help="on, off or on,off: the loop with and without a record")
    parser.add_argument("--cycle-seconds", type=float, default=None,
                        help="time cycles of this length in each run (default: one cycle of --seconds)")
    parser.add_argument("--floor-seconds", type=float, default=60.0,
                        help="wall time of the machine-floor run per rate (at most --seconds)")
    args = parser.parse_args()
    for option, value in (("--seconds", args.seconds), ("--floor-seconds", args.floor_seconds)):
        if not 0 < value <= WEEK_S:  # NaN and infinity included (inf ran for ever, 1e308 overflowed)
            parser.error(f"{option}: more than 0 and at most {WEEK_S} s (a week), got {value:g}")
    if args.cycle_seconds is not None and not (0 < args.cycle_seconds <= args.seconds and MAX_CYCLES >= round(
            args.seconds / args.cycle_seconds) * (1 - 1e-9) and abs(args.seconds / args.cycle_seconds - round(
            args.seconds / args.cycle_seconds)) < 1e-6):
        parser.error(f"--cycle-seconds: a whole fraction of --seconds ({args.seconds:g}), at most {MAX_CYCLES} "
                     f"cycles, got {args.cycle_seconds:g}")
    try:
        rates = [float(r) for r in args.rates.split(",")]
    except ValueError:
        parser.error(f"--rates: comma-separated rates in Hz, got {args.rates!r}")
    policies, workers, recording = args.policies.split(","), args.workers.split(","), args.recording.split(",")
    if not all(50 <= r <= 1000 for r in rates):
        parser.error(f"--rates: each from 50 to 1000 Hz (a profile's range), got {args.rates!r}")
    step_ns = make_cell(CELL).dt_ns
    for rate in rates:  # as the sim-server checks it: its refusal came back as a server that did not answer
        try:
            served_substeps(rate, step_ns)
        except ConfigError as exc:
            parser.error("--rates" + str(exc).removeprefix("--rate-hz"))
    if not set(policies) <= {"onnx100", "python", "sway"} or not set(workers) <= {"thread", "process"}:
        parser.error(f"--policies from onnx100,python,sway and --workers from thread,process; "
                     f"got {args.policies!r} and {args.workers!r}")
    if not set(recording) <= {"on", "off"}:
        parser.error(f"--recording: on, off or on,off; got {args.recording!r}")
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        onnx_path = onnx_model(tmp / "onnx100.onnx", 100.0)
        work = python_work_for(50.0)
        runs, floor = [], []
        for rate in rates:
            floor.append(machine_floor(rate, min(args.floor_seconds, args.seconds)))
            for policy in policies:
                for worker in workers:
                    for record in recording:
                        runs.append(one_run(rate, policy, worker, args.seconds, onnx_path, work,
                                            tmp / f"{rate:.0f}-{policy}-{worker}-{record}", record == "on",
                                            args.cycle_seconds))
    load = os.getloadavg()
    print(json.dumps({"host": {"cpus": os.cpu_count(), "load_avg_1_5_15": [round(x, 2) for x in load],
                               "load_avg_at_start": [round(x, 2) for x in load_before]},
                      "reference": reference_costs(), "machine_floor": floor, "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
