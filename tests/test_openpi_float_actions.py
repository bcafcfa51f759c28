"""An openpi reply's actions must be floats, as an ONNX model's chunk must: an integer chunk fails the call, named.

A server that sent its actions as int64 (truncated degrees and millimetres) ran: success 0 %, 15 limit
interventions, and nothing said the chunk was integers.
"""

import pytest

pytest.importorskip("websockets")
pytest.importorskip("msgpack")
pytest.importorskip("openpi_server.websocket_policy_server")

import yaml  # noqa: E402
from foreign_arm import FOREIGN_NAMES, MAP  # noqa: E402
from test_openpi import ForeignScriptedPolicy, serve  # noqa: E402

from cellguard.policy.adapter import InferenceError  # noqa: E402
from cellguard.policy.openpi import make_openpi_policy  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402


class Typed(ForeignScriptedPolicy):
    """The foreign scripted policy, its actions sent as ``dtype``."""

    def __init__(self, dtype):
        super().__init__()
        self.dtype = dtype

    def infer(self, obs: dict) -> dict:
        reply = super().infer(obs)
        return {**reply, "actions": reply["actions"].astype(self.dtype)}


def _infer(dtype, tmp_path):
    path = tmp_path / "foreign.yaml"
    path.write_text(yaml.safe_dump(MAP))
    with serve(Typed(dtype), {"action_names": FOREIGN_NAMES, "dt_s": 0.02}) as uri:
        cell = ArmPickPlace()
        policy = make_openpi_policy(f"{uri}?map={path}&retries=0&timeout=5", cell)
        try:
            return policy.infer(cell.observe())
        finally:
            policy.close()


@pytest.mark.parametrize("dtype", ["int64", "int32", "uint16", "bool"])
def test_a_reply_of_other_than_floats_fails_the_call_naming_its_dtype(dtype, tmp_path):
    with pytest.raises(InferenceError, match=rf"reply's 'actions' are {dtype}; a chunk is joint targets, floats"):
        _infer(dtype, tmp_path)


@pytest.mark.parametrize("dtype", ["float16", "float32", "float64"])
def test_a_reply_of_floats_gives_the_chunk(dtype, tmp_path):
    assert _infer(dtype, tmp_path).actions.shape == (10, 6)
