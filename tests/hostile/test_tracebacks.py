"""Class 5: inputs that used to end in a traceback are one error line and exit 2; nothing earlier changes."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest
from record_synth import record

from .expect import refused, runner, snapshot
from .scenarios import run_refused, scenario_file
from cellguard.cli import app


def _npy_member(header: str, payload: bytes = b"") -> bytes:
    """A .npy file with a hand-written header (e.g. one declaring 10^11 rows)."""
    text = header + " " * (-(len(header) + 11) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text.encode() + payload


def _zip(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


REPLAYS = {
    "empty.npz": (b"", "not a readable .npz"),
    "objects.npz": (_npz(t=np.zeros(2), actions=np.array([object(), object()], dtype=object)), "dtype"),
    "strings.npz": (_npz(t=np.array(["a", "b"]), actions=np.zeros((2, 3, 6))), "dtype"),
    "huge-header.npz": (_zip({"t.npy": _npy_member("{'descr': '<f8', 'fortran_order': False, 'shape': (100000000000,), }"),
                              "actions.npy": _npy_member("{'descr': '<f8', 'fortran_order': False, 'shape': (1, 1, 6), }",
                                                         bytes(48))}), "declares shape (100000000000,)"),
    "bad-header.npz": (_zip({"t.npy": _npy_member("__import__('os').system('true')")}), "not a readable .npy"),
    "not-zip.npz": (b"[" * 500, "not a readable .npz"),
    # a member name flagged UTF-8 whose bytes are not (found by the hypothesis property)
    "bad-name.npz": (_zip({"t\u00e9.npy": b"x"}).replace(b"t\xc3\xa9", b"t\xc3\x28"), "not a readable .npz"),
}


@pytest.mark.parametrize("name", sorted(REPLAYS))
def test_hostile_replay_files(tmp_path, name):
    data, says = REPLAYS[name]
    (tmp_path / name).write_bytes(data)
    run_refused(tmp_path, scenario_file(tmp_path, policy=f"replay:{tmp_path / name}"), contains=says)


def test_five_hundred_brackets(tmp_path):
    run_refused(tmp_path, scenario_file(tmp_path, text="[" * 500), contains="nested deeper")


ARM_JOINTS = "shoulder_pan,shoulder_lift,elbow,wrist_flex,wrist_roll,gripper"


def small_onnx(path, action_names: str = ARM_JOINTS, **metadata):
    """A one-layer ONNX model of ``time_s`` with six actions named ``action_names``."""
    from cellguard.policy.onnx_export import Mlp, save_mlp_onnx

    rng = np.random.default_rng(0)
    mlp = Mlp(inputs=(("time_s", 1),), weights=(rng.normal(size=(1, 4)), rng.normal(size=(4, 6))),
              biases=(np.zeros(4), np.zeros(6)), x_mean=np.zeros(1), x_std=np.ones(1), y_mean=np.zeros(6),
              y_std=np.ones(6), horizon=1)
    return save_mlp_onnx(mlp, path, {"cellguard.action_names": action_names, **metadata})


def test_non_numeric_and_out_of_range_dt(tmp_path):
    pytest.importorskip("onnx")
    bad = small_onnx(tmp_path / "bad-dt.onnx", **{"cellguard.dt_s": "fast"})
    good = small_onnx(tmp_path / "good.onnx")
    run_refused(tmp_path, scenario_file(tmp_path, policy=f"onnx:{bad}"), contains="cellguard.dt_s")
    for dt in ("1e300", "1e-12", "nan", "-0.02", "inf"):
        run_refused(tmp_path, scenario_file(tmp_path, policy=f"onnx:{good}?dt={dt}"), contains="option dt")


def test_openpi_metadata_dt_not_a_number(tmp_path):
    from .wsserver import serve_bytes

    pytest.importorskip("websockets")
    from cellguard.policy.wire import packb

    metadata = packb({"action_names": ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll",
                                       "gripper"], "dt_s": "fast"})
    with serve_bytes(metadata) as uri:
        run_refused(tmp_path, scenario_file(tmp_path, policy=f"openpi:{uri}"), contains="metadata dt_s")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rec") / "run [1]*?"
    record(folder, 3, 400, events={500: "position_clamp"})
    return folder


def test_export_cycle_beyond_any_integer(recorded, tmp_path):
    before = snapshot(recorded)
    refused(["record", "export", recorded, "-o", tmp_path / "x.csv", "--cycle", str(2**70)], contains="--cycle")
    assert snapshot(recorded) == before and not (tmp_path / "x.csv").exists()


def test_a_folder_named_like_a_glob_pattern_works(recorded):
    result = runner.invoke(app, ["record", "query", str(recorded), "SELECT count(*) AS n FROM cycles"])
    assert result.exit_code == 0 and result.stdout.strip() == '{"n": 3}', result.output
    result = runner.invoke(app, ["record", "info", str(recorded), "--json"])
    assert result.exit_code == 0, result.output


def test_a_damaged_index_part_does_not_stop_export(tmp_path):
    """The index is derived: ``export --cycle`` falls back on the record's own cycle markers."""
    folder = tmp_path / "run"
    record(folder, 2, 300)
    part = next((folder / "index" / "cycles").rglob("*.parquet"))
    part.write_bytes(part.read_bytes()[:40] + b"\0" * 64)
    before = snapshot(folder)
    result = runner.invoke(app, ["record", "export", str(folder), "-o", str(tmp_path / "c.csv"), "--cycle", "1"])
    assert result.exit_code == 0, result.output
    assert len((tmp_path / "c.csv").read_text().splitlines()) > 1
    assert snapshot(folder) == before
