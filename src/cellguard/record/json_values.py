"""Strict JSON values for what the record writes and what `record query` prints, and the record's JSON as read.

Strict JSON has no NaN or infinity: a non-finite number is null. numpy arrays and scalars become lists
and Python numbers; a map's keys keep JSON's own spelling (``true``, ``null``, ``1.5``) and a key JSON
has no type for is its text. A value read from a record nests at most ``MAX_DEPTH`` levels: what reads it
(printing, hashing, the index) recurses once a level or more.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import numpy as np

MAX_DEPTH = 100  # a record's own values nest a few levels (its context about six); Python recurses to 1000


def loads(data: bytes | str):
    """``data`` as JSON; ValueError if it is not JSON or nests deeper than ``MAX_DEPTH`` (a crafted value 3000
    deep made json.loads raise RecursionError, and one 900 deep the printing of ``record info``)."""
    opens = (b"[", b"{") if isinstance(data, bytes) else ("[", "{")
    try:
        value = json.loads(data)
        # no more brackets than MAX_DEPTH cannot nest deeper (most messages): walked only where there are more
        deep = sum(map(data.count, opens)) > MAX_DEPTH and deeper(value, MAX_DEPTH)
    except RecursionError:  # deeper than the interpreter's stack
        deep = True
    if deep:
        raise ValueError(f"JSON nested deeper than {MAX_DEPTH} levels")
    return value


def deeper(value, limit: int) -> bool:
    """Whether ``value`` nests more than ``limit`` lists and maps, found a level at a time (no recursion)."""
    level, depth = ([value] if isinstance(value, (dict, list)) else []), 0
    while level and depth < limit:
        level = [v for c in level for v in (c.values() if isinstance(c, dict) else c) if isinstance(v, (dict, list))]
        depth += 1
    return bool(level)


def plain(value, text: Callable[[object], str] = str):
    """``value`` as plain JSON values, every non-finite float null; ``text``: how a map's key that JSON has no type
    for is spelled."""
    if isinstance(value, dict):
        return {_key(k, text): plain(v, text) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v, text) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist(), text)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _key(key, text: Callable[[object], str]):
    if isinstance(key, np.generic):
        key = key.item()
    if isinstance(key, float) and not math.isfinite(key):
        return json.dumps(key)  # NaN, Infinity: a key, not a value, so it keeps its name
    if key is None or isinstance(key, (str, int, float)):
        return key  # json.dumps spells these keys itself
    return text(key)
