"""A fixed message layout in CDR (little-endian, as ROS 2 writes it) with its ``ros2msg`` text.

The tick stream is the bulk of a record, so it is binary: one message carries many ticks of all
joints as flat arrays. CDR with a ``ros2msg`` schema is what the MCAP tooling already decodes
(Foxglove, ``mcap_ros2``), so the schema declared in the file is the real one and other tools read
the ticks without cellguard. Only the field types cellguard uses are supported; arrays go through
numpy in one copy each, so encoding a batch costs microseconds, not a Python loop per value.
A float32 field stores a value beyond its range (a rejected chunk of 1e308, recorded as the policy sent
it) as an infinity of that sign, which is what a reader gets back; the cast does not warn about it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from cellguard.errors import RecordError

_HEADER = b"\x00\x01\x00\x00"  # CDR_LE encapsulation
_ARRAYS = {"int64[]": np.dtype("<i8"), "int32[]": np.dtype("<i4"), "float32[]": np.dtype("<f4"),
           "float64[]": np.dtype("<f8")}
_SCALARS = {"int64": struct.Struct("<q"), "uint32": struct.Struct("<I")}
_U32 = struct.Struct("<I")


@dataclass(frozen=True)
class CdrLayout:
    """An ordered set of ``(name, type, comment)`` fields; types: int64, uint32, string[], <num>[]."""

    name: str  # e.g. "cellguard_msgs/TickBatch"
    doc: str
    fields: tuple[tuple[str, str, str], ...]

    def __post_init__(self):
        for field, kind, _ in self.fields:
            if kind not in _ARRAYS and kind not in _SCALARS and kind != "string[]":
                raise ValueError(f"{self.name}.{field}: unsupported CDR type {kind!r}")

    def ros2msg(self) -> str:
        """The schema text stored in the MCAP file (``ros2msg`` encoding)."""
        lines = [f"# {line}" for line in self.doc.splitlines()]
        lines += [f"{kind} {field}" + (f"  # {comment}" if comment else "") for field, kind, comment in self.fields]
        return "\n".join(lines) + "\n"

    def encode(self, values: dict) -> bytes:
        """Serialise ``values`` (name -> int, list of str, or array) to one CDR message."""
        out = bytearray(_HEADER)
        for field, kind, _ in self.fields:
            value = values[field]
            if kind in _SCALARS:
                _pad(out, _SCALARS[kind].size)
                out += _SCALARS[kind].pack(value)
            elif kind == "string[]":
                _pad(out, 4)
                out += _U32.pack(len(value))
                for text in value:
                    raw = text.encode() + b"\0"
                    _pad(out, 4)
                    out += _U32.pack(len(raw)) + raw
            else:
                with np.errstate(over="ignore"):
                    array = np.ascontiguousarray(value, dtype=_ARRAYS[kind]).reshape(-1)
                _pad(out, 4)
                out += _U32.pack(array.size)
                _pad(out, array.itemsize)
                out += array.tobytes()
        return bytes(out)

    def decode(self, data: bytes) -> dict:
        """Parse one message written by :meth:`encode`; RecordError if it is cut short."""
        if data[:4] != _HEADER:
            raise RecordError(f"{self.name}: not a little-endian CDR message")
        view, offset, out = memoryview(data), 4, {}
        try:
            for field, kind, _ in self.fields:
                if kind in _SCALARS:
                    offset = _align(offset, _SCALARS[kind].size)
                    out[field] = _SCALARS[kind].unpack_from(view, offset)[0]
                    offset += _SCALARS[kind].size
                    continue
                offset = _align(offset, 4)
                (count,) = _U32.unpack_from(view, offset)
                offset += 4
                if kind == "string[]":
                    texts = []
                    for _ in range(count):
                        offset = _align(offset, 4)
                        (size,) = _U32.unpack_from(view, offset)
                        texts.append(bytes(view[offset + 4:offset + 3 + size]).decode())
                        offset += 4 + size
                    out[field] = texts
                else:
                    dtype = _ARRAYS[kind]
                    offset = _align(offset, dtype.itemsize)
                    out[field] = np.frombuffer(view, dtype, count, offset).copy()
                    offset += count * dtype.itemsize
        except (struct.error, ValueError, UnicodeDecodeError) as exc:
            raise RecordError(f"{self.name}: message cut short or malformed ({exc})") from None
        return out


def _pad(out: bytearray, size: int) -> None:
    out += b"\0" * ((-(len(out) - 4)) % size)


def _align(offset: int, size: int) -> int:
    return offset + (-(offset - 4)) % size
