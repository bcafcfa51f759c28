"""The declared schemas are the real ones: our CDR round-trips, and mcap_ros2 decodes it from the schema text."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mcap.reader import make_reader
from record_synth import record

from cellguard.errors import RecordError
from cellguard.record.schemas import CHUNK, TICKS

mcap_ros2 = pytest.importorskip("mcap_ros2.decoder", reason="mcap-ros2-support (dev extra) decodes ros2msg/cdr")

_floats = hnp.arrays(np.float32, st.integers(0, 40), elements=st.floats(-1e6, 1e6, width=32))


@settings(max_examples=50, deadline=None)
@given(n=st.integers(0, 30), names=st.lists(st.text(min_size=0, max_size=8), min_size=1, max_size=7), data=st.data())
def test_tick_batch_round_trip(n, names, data):
    dof = len(names)
    arrays = {f: data.draw(hnp.arrays(np.float32, n * dof, elements=st.floats(-1e6, 1e6, width=32)))
              for f in ("q_ref", "q_cmd", "q_meas", "qd_meas", "effort", "current")}
    t = data.draw(hnp.arrays(np.int64, n, elements=st.integers(-(2**62), 2**62)))
    values = {"joints": names, "t_ns": t, "cycle": np.arange(n, dtype=np.int32), **arrays}
    out = TICKS.decode(TICKS.encode(values))
    assert out["joints"] == names
    for key, want in values.items():
        if key != "joints":
            np.testing.assert_array_equal(out[key], want)


@settings(max_examples=30, deadline=None)
@given(actions=_floats, t=st.integers(-(2**62), 2**62))
def test_chunk_round_trip(actions, t):
    values = {"t_obs_ns": t, "t_received_ns": 5, "latency_ns": 7, "dt_ns": 20_000_000, "dof": 1,
              "actions": actions, "uncertainty": np.zeros(0)}
    out = CHUNK.decode(CHUNK.encode(values))
    assert out["t_obs_ns"] == t and out["dof"] == 1
    np.testing.assert_array_equal(out["actions"], actions)


def test_a_cut_message_is_a_record_error():
    data = TICKS.encode({"joints": ["a"], "t_ns": [1, 2], "cycle": [0, 0], **{f: [1.0, 2.0] for f in
                         ("q_ref", "q_cmd", "q_meas", "qd_meas", "effort", "current")}})
    with pytest.raises(RecordError, match="TickBatch"):
        TICKS.decode(data[:-5])


def test_mcap_ros2_decodes_the_tick_stream_from_the_declared_schema(tmp_path):
    record(tmp_path, 2, 500)
    with open(tmp_path / "record.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[mcap_ros2.DecoderFactory()])
        seen = 0
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=["/ticks/decimated"]):
            ours = TICKS.decode(message.data)
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            assert list(decoded.joints) == ours["joints"]
            assert list(decoded.t_ns) == ours["t_ns"].tolist()
            np.testing.assert_array_equal(np.asarray(decoded.current, dtype=np.float32), ours["current"])
            seen += 1
    assert seen > 5
