"""``policy: replay:FILE.npz``: recorded streams replay as recorded; bad files give one clear error."""

from __future__ import annotations

import struct
import zipfile

import numpy as np
import pytest

from cellguard.errors import ConfigError
from cellguard.policy import replay
from cellguard.policy.registry import make_policy
from cellguard.robot.registry import make_cell
from cellguard.runtime import Run
from cellguard.scenario import parse_scenario

CELL = make_cell("arm-pick-place")


DT = np.array(0.02)


def _write(path, **arrays):
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("arrays, says", [
    ({"actions": np.zeros((2, 3, 6))}, "missing array 't'"),
    ({"t": np.zeros(2)}, "missing array 'actions'"),
    ({"t": np.zeros(2), "actions": np.zeros((2, 3, 6))}, "missing array 'dt'"),  # was played at an assumed 20 ms
    ({"t": np.zeros(2), "actions": np.zeros((2, 3, 5)), "dt": DT}, "actions must have shape (N=2, H>0, D=6)"),
    ({"t": np.zeros(3), "actions": np.zeros((2, 3, 6)), "dt": DT}, "actions must have shape"),
    ({"t": np.array([0.0, np.nan]), "actions": np.zeros((2, 3, 6)), "dt": DT}, "t must be"),
    ({"t": np.zeros(2), "actions": np.zeros((2, 3, 6)), "uncertainty": np.zeros(2), "dt": DT},
     "uncertainty must have shape"),
    ({"t": np.zeros(2), "actions": np.zeros((2, 3, 6)), "dt": np.array([0.02, 0.02])}, "dt must be"),
    ({"t": np.zeros(2), "actions": np.zeros((2, 3, 6)), "extra": np.zeros(1), "dt": DT}, "unknown array"),
    # finite, but past int64 nanoseconds: RuntimeWarnings, then every chunk stale
    ({"t": np.array([0.0, 1e300]), "actions": np.zeros((2, 3, 6)), "dt": DT},
     "t must be finite seconds within +-1e+09 s"),
    ({"t": np.array([-2e9, 0.0]), "actions": np.zeros((2, 3, 6)), "dt": DT}, "got t[0] = -2000000000.0"),
    ({"t": np.zeros(2), "actions": np.zeros((2, 3, 6)), "dt": np.array(True)}, "dt is of dtype bool"),
    ({"t": np.zeros(2, dtype=bool), "actions": np.zeros((2, 3, 6)), "dt": DT}, "t is of dtype bool"),
])
def test_bad_files_raise_one_error_naming_what_is_wrong(tmp_path, arrays, says):
    path = _write(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ConfigError) as info:
        make_policy(f"replay:{path}", CELL)
    assert says in str(info.value) and str(path) in str(info.value)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        make_policy(f"replay:{tmp_path / 'none.npz'}", CELL)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ConfigError, match="not a readable .npz"):
        make_policy(f"replay:{tmp_path / 'junk.npz'}", CELL)
    with pytest.raises(ConfigError, match="needs a file"):
        make_policy("replay:", CELL)


def test_records_are_handed_out_in_order_once_due(tmp_path):
    actions = np.repeat(CELL.q_home[None, None], 3, axis=0).repeat(4, axis=1)
    path = _write(tmp_path / "s.npz", t=np.array([0.0, 0.1, 0.05]), actions=actions, uncertainty=np.zeros((3, 4)),
                  dt=DT)
    policy = make_policy(f"replay:{path}", CELL)
    obs = CELL.observe()
    first = policy.infer(obs)
    assert first.t_obs_ns == obs.t_ns and first.uncertainty.shape == (4,)
    from dataclasses import replace

    assert policy.infer(replace(obs, t_ns=obs.t_ns + 50_000_000)) is first  # the next is due only at 0.1 s
    second = policy.infer(replace(obs, t_ns=obs.t_ns + 100_000_000))
    third = policy.infer(replace(obs, t_ns=obs.t_ns + 120_000_000))  # recorded out of order: replayed so
    assert second.t_obs_ns - obs.t_ns == 100_000_000 and third.t_obs_ns - obs.t_ns == 50_000_000


def test_a_file_cut_from_a_longer_record_plays_from_its_first_chunk(tmp_path):
    """``t`` starting at 0.3 s: the first chunk, handed out at once, was stamped 0.3 s after the observation it
    answers, the executor refused it as from the future and the run ended "policy lost"."""
    n, h = 60, 10
    actions = CELL.q_home + np.linspace(0.0, 0.2, n * h).reshape(n, h, 1) * (np.arange(6) < 5)
    path = _write(tmp_path / "cut.npz", t=0.3 + np.arange(n) * 0.05, actions=actions, dt=DT)
    obs = CELL.observe()
    assert make_policy(f"replay:{path}", CELL).infer(obs).t_obs_ns == obs.t_ns
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{path}", "acceptance_cycles": 1,
                              "production_cycles": 0, "cycle": {"source": "time", "seconds": 3.0}}))
    run.cycle()
    assert not run.policy_lost and "chunk_rejected" not in {e.kind for e in run.events}


def test_an_adversarial_replay_runs_through_the_arm_cell_inside_the_limits(tmp_path):
    rng = np.random.default_rng(4)
    n, h = 40, 10
    home = CELL.q_home
    actions = home + rng.normal(0.0, 0.3, (n, h, 6)) * (np.arange(6) < 5)
    actions[5, 3, 1] = np.nan
    actions[9] *= 1e9
    t = np.arange(n) * 0.05
    t[20:] += 0.6  # a silence the watchdog must catch
    path = _write(tmp_path / "adversarial.npz", t=t, actions=actions, dt=np.array(0.02))
    scenario = parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{path}", "acceptance_cycles": 1,
                               "production_cycles": 0})
    run = Run(scenario)
    sent = []
    original = run.guard.envelope.apply

    def apply(*args, **kwargs):
        setpoint, events = original(*args, **kwargs)
        sent.append(setpoint.copy())
        return setpoint, events

    run.guard.envelope.apply = apply
    run.cycle()
    kinds = {e.kind for e in run.events}
    assert {"chunk_rejected", "watchdog_stop"} <= kinds
    q = np.array(sent)
    profile = CELL.profile
    assert (q >= profile.q_min).all() and (q <= profile.q_max).all()
    v = np.diff(q, axis=0) / 1e-3
    assert (np.abs(v) <= profile.array("velocity") * 1.002).all()


def test_a_directory_of_many_entries_is_refused_before_zipfile_parses_it(tmp_path, monkeypatch):
    """A central directory of millions of entries, each naming t.npy, took 2.5 GB and 43 s to be refused."""
    entry = struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, 0, 0, 0, 0, 0, 0, 5, 0, 0, 0, 0, 0, 0) + b"t.npy"
    count = 70_000  # past 65535: a zip64 end record, as the crafted file had
    local = struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 0, 0, 0, 0, 0, 0, 5, 0) + b"t.npy"
    directory = entry * count
    end64 = struct.pack("<IQHHIIQQQQ", 0x06064B50, 44, 45, 45, 0, 0, count, count, len(directory), len(local))
    locator = struct.pack("<IIQI", 0x07064B50, 0, len(local) + len(directory), 1)
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 0xFFFF, 0xFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0)
    path = tmp_path / "many.npz"
    path.write_bytes(local + directory + end64 + locator + end)
    monkeypatch.setattr(zipfile, "ZipFile", None)  # never reached
    with pytest.raises(ConfigError, match="its directory lists 70000 members"):
        replay.read_npz(path, "replay file", ("t", "actions", "uncertainty", "dt"), ("t", "actions"))
