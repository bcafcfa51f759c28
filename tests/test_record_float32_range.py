"""A chunk value beyond float32's range is recorded as an infinity of its sign, without a warning on stderr.

A float64 ONNX model answering 1e308 got its chunk rejected, and recording it as it came printed numpy's
``RuntimeWarning: overflow encountered in cast`` in the middle of the run's output.
"""

from __future__ import annotations

import warnings

import numpy as np

from cellguard.record.schemas import CHUNK


def test_a_value_beyond_float32_reads_back_as_an_infinity_of_its_sign_and_warns_nothing():
    actions = np.array([[1e308, -1e308, np.nan, 0.25, 3.5e38, -1e-50]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        data = CHUNK.encode({"t_obs_ns": 1, "t_received_ns": 2, "latency_ns": 1, "dt_ns": 20_000_000, "dof": 6,
                             "actions": actions, "uncertainty": np.zeros(0)})
    back = CHUNK.decode(data)["actions"].astype(np.float64)
    assert back[:2].tolist() == [np.inf, -np.inf] and np.isnan(back[2])
    assert back[3] == 0.25 and back[4] == np.inf and back[5] == 0.0
