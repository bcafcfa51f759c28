"""Class 6: inputs are bounded before they are read or allocated, with the limit in the message."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from .scenarios import run_refused, scenario_file
from cellguard.errors import ConfigError
from cellguard.policy.replay import read_npz


def test_dev_zero_as_a_scenario(tmp_path):
    run_refused(tmp_path, "/dev/zero", contains="limit of 1048576 bytes")


def test_a_50_mb_fault_list(tmp_path):
    path = tmp_path / "faults.yaml"
    with path.open("w") as f:
        f.write("cell: arm-pick-place\nfaults:\n")
        line = "  - {kind: tool_slip, at_cycle: 5}\n"
        f.write(line * (50_000_000 // len(line)))
    run_refused(tmp_path, path, contains="limit of 1048576 bytes")


def test_an_alias_bomb(tmp_path):
    text = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8))
    run_refused(tmp_path, scenario_file(tmp_path, text=text), contains="expands to more than")


def test_too_many_faults_even_in_a_small_file(tmp_path):
    text = "cell: arm-pick-place\nfaults: [" + ", ".join(["{kind: tool_slip, at_cycle: 5}"] * 10_001) + "]\n"
    run_refused(tmp_path, scenario_file(tmp_path, text=text), contains="faults")


def test_compressed_replay_expansion_is_bounded(tmp_path):
    """A 100 kB archive expanding to 100 MB: refused from its declared size, before decompressing."""
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("t.npy", _npy(np.zeros(2)))
        with z.open("actions.npy", "w", force_zip64=True) as member:
            member.write(_npy_header((100 * 2**20 // 48, 1, 6)))
            zeros = bytes(2**20)
            for _ in range(100):
                member.write(zeros)
    assert path.stat().st_size < 1_000_000
    with pytest.raises(ConfigError, match="over the limit of 10485760 bytes"):
        read_npz(path, "replay", ("t", "actions"), ("t", "actions"), max_bytes=10 << 20)


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _npy_header(shape: tuple) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    return buf.getvalue()  # magic, version and the padded header


def test_openpi_messages_over_the_cap(tmp_path):
    pytest.importorskip("websockets")
    from .wsserver import serve_bytes
    from cellguard.policy.openpi import MAX_MESSAGE

    with serve_bytes(bytes(MAX_MESSAGE + 1)) as uri:
        line = run_refused(tmp_path, scenario_file(tmp_path, policy=f"openpi:{uri}?timeout=5"),
                           contains="cannot connect")
    assert "PayloadTooBig" in line or "ConnectionClosed" in line
