"""Standard ROS 2 messages in CDR, so that Foxglove and other MCAP tools show a record without cellguard.

``sensor_msgs/msg/JointState`` (joints by name, per tick), ``tf2_msgs/msg/TFMessage`` (link poses
for the 3D panel), ``rcl_interfaces/msg/Log`` (events in the log panel) and ``std_msgs/msg/String``
(the robot description). Schema texts are the ROS 2 definitions with their dependencies in the
``ros2msg`` form rosbag2 writes. Joint states are encoded a batch at a time with numpy: every
message of a record has the same layout (names fixed), so one template row is filled per tick.
"""

from __future__ import annotations

import struct

import numpy as np

_SEP = "\n" + "=" * 80 + "\n"
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"


def _schema(main: str, *deps: tuple[str, str]) -> str:
    return main + "".join(f"{_SEP}MSG: {name}\n{text}" for name, text in deps)


JOINT_STATE = ("sensor_msgs/msg/JointState", _schema(
    "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
    ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME)))
TF_MESSAGE = ("tf2_msgs/msg/TFMessage", _schema(
    "geometry_msgs/TransformStamped[] transforms\n",
    ("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\n"
                                       "geometry_msgs/Transform transform\n"),
    ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME),
    ("geometry_msgs/Transform", "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n")))
LOG = ("rcl_interfaces/msg/Log", _schema(
    "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n"
    "builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\nstring file\nstring function\nuint32 line\n",
    ("builtin_interfaces/Time", _TIME)))
STRING = ("std_msgs/msg/String", "string data\n")

DEBUG, INFO, WARN, ERROR, FATAL = 10, 20, 30, 40, 50


class CdrBuffer:
    """Little-endian CDR with alignment counted from the end of the 4-byte encapsulation header."""

    def __init__(self):
        self.out = bytearray(b"\x00\x01\x00\x00")

    def align(self, size: int) -> None:
        self.out += b"\0" * ((-(len(self.out) - 4)) % size)

    def pack(self, fmt: str, *values) -> None:
        """Values of one type (``fmt`` like "I" or "ddd"), aligned to that type's size."""
        self.align(struct.calcsize("<" + fmt[0]))
        self.out += struct.pack("<" + fmt, *values)

    def string(self, text: str) -> None:
        raw = text.encode() + b"\0"
        self.pack("I", len(raw))
        self.out += raw

    def stamp(self, wall_ns: int) -> None:
        sec, nsec = divmod(int(wall_ns), 1_000_000_000)
        self.pack("i", sec)
        self.pack("I", nsec)

    def bytes(self) -> bytes:
        return bytes(self.out)


def log_message(wall_ns: int, level: int, name: str, text: str) -> bytes:
    buf = CdrBuffer()
    buf.stamp(wall_ns)
    buf.pack("B", level)
    for s in (name, text, "", ""):
        buf.string(s)
    buf.pack("I", 0)
    return buf.bytes()


def string_message(text: str) -> bytes:
    buf = CdrBuffer()
    buf.string(text)
    return buf.bytes()


class TfEncoder:
    """``tf2_msgs/TFMessage`` for a fixed list of (parent, child) frames, many ticks per call."""

    def __init__(self, frames: list[tuple[str, str]]):
        buf = CdrBuffer()
        buf.pack("I", len(frames))
        self._stamps, self._poses = [], []
        for parent, child in frames:
            buf.align(4)
            self._stamps.append(len(buf.out))
            buf.stamp(0)
            buf.string(parent)
            buf.string(child)
            buf.align(8)
            self._poses.append(len(buf.out))  # translation x y z, rotation x y z w: seven float64
            buf.out += bytes(56)
        self._template = np.frombuffer(buf.bytes(), dtype=np.uint8)

    def encode(self, wall_ns: np.ndarray, poses: np.ndarray) -> list[bytes]:
        """One message per row: ``wall_ns`` (n,) epoch time, ``poses`` (n, frames, 7) as ``JointFrames.poses``."""
        n = len(wall_ns)
        rows = np.repeat(self._template[None, :], n, axis=0)
        sec, nsec = _stamp_bytes(wall_ns)
        poses = np.ascontiguousarray(poses, dtype="<f8").reshape(n, len(self._poses), 7)
        for k, (stamp, pose) in enumerate(zip(self._stamps, self._poses)):
            rows[:, stamp:stamp + 4], rows[:, stamp + 4:stamp + 8] = sec, nsec
            rows[:, pose:pose + 56] = poses[:, k].view(np.uint8).reshape(n, 56)
        return [row.tobytes() for row in rows]


class JointStateEncoder:
    """JointState messages for a fixed list of joint names, many ticks per call."""

    def __init__(self, names: tuple[str, ...], frame_id: str = ""):
        self.dof = len(names)
        buf = CdrBuffer()
        buf.stamp(0)
        buf.string(frame_id)
        buf.pack("I", len(names))
        for name in names:
            buf.string(name)
        self._arrays = []
        for _ in range(3):
            buf.pack("I", self.dof)
            buf.align(8)
            self._arrays.append(len(buf.out))
            buf.out += bytes(8 * self.dof)
        self._template = np.frombuffer(buf.bytes(), dtype=np.uint8)

    def encode(self, wall_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray, effort: np.ndarray
               ) -> list[bytes]:
        """One message per row: ``wall_ns`` (n,) epoch time, arrays (n, dof) SI."""
        n = len(wall_ns)
        rows = np.repeat(self._template[None, :], n, axis=0)
        rows[:, 4:8], rows[:, 8:12] = _stamp_bytes(wall_ns)
        for at, values in zip(self._arrays, (position, velocity, effort)):
            block = np.ascontiguousarray(values, dtype="<f8").reshape(n, self.dof)
            rows[:, at:at + 8 * self.dof] = block.view(np.uint8).reshape(n, 8 * self.dof)
        return [row.tobytes() for row in rows]


def _stamp_bytes(wall_ns) -> tuple[np.ndarray, np.ndarray]:
    """``builtin_interfaces/Time`` of each epoch time (n,) [ns] as CDR bytes: sec (n, 4), nanosec (n, 4)."""
    n = len(wall_ns)
    sec, nsec = np.divmod(np.asarray(wall_ns, dtype=np.int64), 1_000_000_000)
    return sec.astype("<i4").view(np.uint8).reshape(n, 4), nsec.astype("<u4").view(np.uint8).reshape(n, 4)
