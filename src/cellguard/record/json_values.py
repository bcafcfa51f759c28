"""Strict JSON values for what the record writes and what `record query` prints.

Strict JSON has no NaN or infinity: a non-finite number is null. numpy arrays and scalars become lists
and Python numbers; a map's keys keep JSON's own spelling (``true``, ``null``, ``1.5``) and a key JSON
has no type for is its text.
"""

from __future__ import annotations

import json
import math

import numpy as np


def plain(value):
    """``value`` as plain JSON values, every non-finite float null."""
    if isinstance(value, dict):
        return {_key(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _key(key):
    if isinstance(key, np.generic):
        key = key.item()
    if isinstance(key, float) and not math.isfinite(key):
        return json.dumps(key)  # NaN, Infinity: a key, not a value, so it keeps its name
    if key is None or isinstance(key, (str, int, float)):
        return key  # json.dumps spells these keys itself
    return str(key)
