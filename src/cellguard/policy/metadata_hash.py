"""The sha256 of a policy server's metadata, as a release pins it: canonical, so the same metadata gives the same
hash in every run, whatever the order its server wrote its maps in.

The text hashed is JSON as ``json.dumps(sort_keys=True)`` wrote it for metadata of text keys and JSON values (a
release pinned before reads the same), extended to what msgpack and openpi's msgpack_numpy decode besides: a numpy
scalar or array by its dtype (little-endian) and value, bytes by their content, and a map whose keys are not all
text (an int, nil) with its keys in one total order (nil, then numbers, then texts, then the rest by their canonical
text; ties by the value). What has no such form (msgpack's ext types and timestamps, nesting deeper than
``MAX_DEPTH``) is refused, naming the metadata key that holds it.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from cellguard.errors import ConfigError

MAX_DEPTH = 400  # nested lists and maps in one metadata value; json.dumps overflowed Python's stack near 1,000
_KEPT = (str, int, float, list, bool)  # the top-level values hashed; the rest were left out, and still are
_PLAIN = {str, int, float, bool, type(None)}


class _Unhashable(Exception):
    """A value with no canonical form; the message says what it is."""


def metadata_sha256(uri: str, metadata: dict) -> str:
    """sha256 of ``{"uri": uri, "metadata": ...}`` (its values of ``_KEPT`` types); ConfigError naming the key of a
    value that cannot be hashed."""
    entries = []
    for key, value in metadata.items():
        if not isinstance(value, _KEPT):
            continue
        try:
            entries.append(_entry(key, value, 1))
        except _Unhashable as exc:
            raise ConfigError(f"policy: openpi:{uri}: server metadata {key!r:.60} holds {exc}, which cannot be "
                              f"hashed for the release's pin of the server; have the server send numbers, text, "
                              f"bytes, lists, maps or numpy arrays") from None
    text = f'{{"metadata": {_mapping(entries)}, "uri": {json.dumps(uri)}}}'  # its keys in order, as json.dumps wrote
    return hashlib.sha256(text.encode()).hexdigest()


def _text(value, depth: int) -> str:
    """The canonical JSON text of ``value``."""
    if depth > MAX_DEPTH:
        raise _Unhashable(f"lists or maps nested deeper than {MAX_DEPTH} levels")
    if value is None or isinstance(value, (bool, int, float, str)):  # numpy's float64 is a float: as before
        return json.dumps(value)
    if isinstance(value, list):
        if {type(v) for v in value} <= _PLAIN:  # json.dumps writes it alike, in C: a long list of numbers
            return json.dumps(value)
        return "[" + ", ".join(_text(v, depth + 1) for v in value) + "]"
    if isinstance(value, dict):
        return _mapping([_entry(k, v, depth) for k, v in value.items()])
    if isinstance(value, bytes):
        return _text({"__bytes__": value.hex()}, depth)
    if isinstance(value, np.generic):
        item = value.item()  # a long double's item is itself: its bytes (its repr differs between numpy versions)
        little = np.asarray(value, dtype=value.dtype.newbyteorder("<"))
        return _text({"__npgeneric__": little.dtype.str,
                      "data": little.tobytes().hex() if isinstance(item, np.generic) else item}, depth)
    if isinstance(value, np.ndarray):
        little = np.ascontiguousarray(value, dtype=value.dtype.newbyteorder("<"))
        return _text({"__ndarray__": little.dtype.str, "shape": list(little.shape),
                      "sha256": hashlib.sha256(little.tobytes()).hexdigest()}, depth)
    raise _Unhashable(f"a {type(value).__name__}")


def _entry(key, value, depth: int) -> tuple:
    """One entry of a map at ``depth``: its place in the order, its key's text and its value's."""
    return _order(key), _key_text(key, depth), _text(value, depth + 1)


def _mapping(entries: list[tuple]) -> str:
    """A map's canonical text from its ``_entry``s: in their total order (ties by the value's text)."""
    return "{" + ", ".join(f"{json.dumps(key)}: {value}" for _, key, value in sorted(entries)) + "}"


def _order(key) -> tuple:
    """A total order over keys of any type: texts as ``sorted`` put them, numbers by value (NaN after them)."""
    if key is None:
        return (0,)
    if isinstance(key, (int, float)):  # bool among them, as True == 1
        return (1, 0, key) if key == key else (1, 1)
    return (2,) if isinstance(key, str) else (3,)


def _key_text(key, depth: int) -> str:
    """A key as JSON text: a text as it is, nil, a boolean or a number as ``json.dumps`` wrote it, the rest as its
    canonical text."""
    if isinstance(key, str):
        return key
    return json.dumps(key) if key is None or isinstance(key, (int, float)) else _text(key, depth + 1)
