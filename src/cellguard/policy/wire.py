"""msgpack with numpy arrays, as openpi's websocket protocol encodes them; never pickle.

An array travels as ``{"__ndarray__": True, "data": bytes, "dtype": str, "shape": list}`` and
a numpy scalar as ``{"__npgeneric__": True, "data": item, "dtype": str}``. Object, void and
complex dtypes are refused both ways: decoding builds arrays only from raw bytes of a plain
numeric or boolean dtype, so nothing that arrives over a network can run code.
"""

from __future__ import annotations

import msgpack
import numpy as np

from cellguard.errors import CellguardError

_ALLOWED_KINDS = frozenset("biuf")  # bool, signed, unsigned, float


class WireError(CellguardError, ValueError):
    """A message that is not a well-formed openpi msgpack document."""


def _check_dtype(dtype: np.dtype) -> None:
    if dtype.kind not in _ALLOWED_KINDS:
        raise WireError(f"dtype {dtype.str!r} is not allowed on the wire (kinds: bool, int, uint, float)")


def _encode(obj):
    if isinstance(obj, np.ndarray):
        _check_dtype(obj.dtype)
        return {b"__ndarray__": True, b"data": np.ascontiguousarray(obj).tobytes(), b"dtype": obj.dtype.str,
                b"shape": list(obj.shape)}
    if isinstance(obj, np.generic):
        _check_dtype(obj.dtype)
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _decode(obj: dict):
    if b"__ndarray__" in obj:
        try:
            dtype = np.dtype(obj[b"dtype"])
            _check_dtype(dtype)
            shape = tuple(int(n) for n in obj[b"shape"])
            return np.frombuffer(obj[b"data"], dtype=dtype).reshape(shape).copy()
        except (KeyError, TypeError, ValueError) as exc:
            raise WireError(f"malformed array: {exc}") from None
    if b"__npgeneric__" in obj:
        try:
            dtype = np.dtype(obj[b"dtype"])
            _check_dtype(dtype)
            return dtype.type(obj[b"data"])
        except (KeyError, TypeError, ValueError) as exc:
            raise WireError(f"malformed scalar: {exc}") from None
    return obj


def packb(obj) -> bytes:
    """Encode a document of dicts, lists, strings, numbers and numeric numpy arrays."""
    return msgpack.packb(obj, default=_encode, use_bin_type=True)


def unpackb(data: bytes, max_bytes: int = 64 << 20):
    """Decode a message; arrays come back as numpy arrays (owned, writable)."""
    if len(data) > max_bytes:
        raise WireError(f"message of {len(data)} bytes exceeds the limit of {max_bytes}")
    try:
        return msgpack.unpackb(data, object_hook=_decode, raw=False, strict_map_key=False)
    except WireError:
        raise
    except (msgpack.ExtraData, msgpack.FormatError, msgpack.StackError, ValueError, TypeError) as exc:
        raise WireError(f"not a msgpack document: {type(exc).__name__}") from None
