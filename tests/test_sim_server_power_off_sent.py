"""A power-off reaches a real ``cellguard sim-server`` even when the loop writes nothing after it.

The bridge's power-off was a flag that went out with the next command; after a lost link the loop removes power
and writes nothing more, so a server whose state publisher hung (it still heard every command) kept its drives
powered while the record said ``power_removed``. A power-off that cannot be sent is an event saying so.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
import time

import numpy as np
import pytest
from sim_server_util import HOME, scenario, server_counters, start_server, sway_file

from cellguard.control.events import EventKind
from cellguard.robot.bridges.sim_server import STATE_HEAD, SimServerRobot
from cellguard.runtime import Run, run_scenario
from cellguard.runtime.link import RobotLink
from cellguard.scenario import parse_scenario

DOF = len(HOME)


@pytest.fixture
def server_50hz():
    """Served at 50 Hz: a stopped server queues about 20 commands in the 0.4 s before the link is lost (at 1 kHz,
    hundreds for one socket buffer), so the kernel keeps the last one."""
    proc, port = start_server("--rate-hz", "50")
    yield proc, port
    proc.kill()  # stopped or not
    proc.wait()


def drive_effort(port: int) -> np.ndarray:
    """The served drives' effort, from a state packet to a new client (zero for every joint: power is off)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer:
        peer.connect(("127.0.0.1", port))
        peer.settimeout(5.0)
        peer.send(b"H")
        while (packet := peer.recv(65536))[:1] != b"S":
            pass
        peer.send(b"G")
    return np.frombuffer(packet, dtype="<f8", offset=STATE_HEAD.size)[2 * DOF:3 * DOF]


def test_a_server_whose_states_stop_mid_cycle_gets_the_power_off_the_record_states(server_50hz, tmp_path):
    """The server process stopped mid-cycle (SIGSTOP): its socket still takes every command, none is answered. The
    loop loses the link and removes power; resumed before the run says goodbye, the server must find the power-off
    among the commands queued for it."""
    proc, port = server_50hz
    stopped = threading.Event()

    def stop():  # mid-cycle: once the loop has commanded for 0.5 s
        while server_counters(port).get("commands", 0) < 25:
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGSTOP)
        stopped.set()

    class ResumedBeforeGoodbye(Run):
        def close(self):
            """Resume the server while this run is still its client (a server that finds its client gone refuses
            what it queued from it), and wait until it answers: every command sent before is taken by then."""
            os.kill(proc.pid, signal.SIGCONT)
            while not server_counters(port):
                pass
            super().close()

    threading.Thread(target=stop, daemon=True).start()
    raw = scenario(port, sway_file(tmp_path / "sway.npz"))
    raw["cycle"]["seconds"] = 5.0
    run = ResumedBeforeGoodbye(parse_scenario(raw))
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    assert stopped.is_set()
    removed = [e for e in summary["events"] if e["kind"] == "power_removed"]
    # the link lost (category 0 at once) or, on a loaded host, its read time-out's category 1 stop completed first
    assert removed and "robot link" in removed[0]["reason"], summary["events"]
    assert not [e for e in summary["events"] if "power-off not confirmed" in e["reason"]]  # it was sent
    effort = drive_effort(port)
    assert np.all(effort == 0.0), f"the served drives are still powered: effort {effort}"


def test_a_power_off_that_cannot_be_sent_is_an_event_saying_it_was_not_confirmed():
    """The server killed: the power-off's send is refused. A write fault recorded before it (here a setpoint of
    the wrong shape, refused by the bridge) does not hide it."""
    proc, port = start_server()
    try:
        robot = SimServerRobot(("127.0.0.1", port))
        events: list = []
        link = RobotLink(robot, events, stop_category=1)
        link.read(0)
        link.write(0, np.zeros(DOF + 1))  # refused before the wire: the run's first robot_write_failed
        proc.kill()
        proc.wait()
        link.write(1, HOME)  # goes out; the closed port answers it (ICMP), so the next send is refused
        time.sleep(0.05)
        link.power_off(2)
        off = [e for e in events if e.kind == EventKind.ROBOT_WRITE_FAILED and e.t_ns == 2]
        assert off and off[0].reason.startswith("drive power-off not confirmed: RobotLinkError: sim-server refused "
                                                "the command (process gone)"), events
        assert off[0].category == 1 and link.stop == 1
        robot.close()
    finally:
        proc.kill()
        proc.wait()
