"""``policy: replay:FILE.npz``: recorded chunks played back, to reproduce an incident or test a stream.

The file holds ``t`` (N,) [s], when each chunk's observation was taken, counted from the start
of the cycle; ``actions`` (N, H, D) in the cell's joint order and SI units; optionally
``uncertainty`` (N, H); and ``dt`` (a scalar [s], the step of every chunk; required: a file without it was
played at an assumed 20 ms, as the other sources once were).
Each cycle replays the file from its start. Records are handed out in file order once their
time has come, stamped with that time, so late, out-of-order and silent streams replay as
recorded; the first is handed out at once, stamped no later than the observation it answers (a file whose
``t`` starts after 0 was stamped ahead of it: the executor refuses such a chunk); the values are not checked here (NaN and wrong sizes are what such streams are for):
the executor refuses bad chunks with events. A malformed *file* is refused at load, naming what
is wrong.
"""

from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path

import numpy as np

from cellguard.errors import ConfigError
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.state import Observation

OPTIONS: dict[str, str] = {}  # replay:FILE takes no options: the whole argument is the file
TAKES_FILE = True  # frozen in a release by its absolute path (cellguard.policy.registry)

MAX_BYTES = 512 << 20  # [bytes] the largest replay file, and the most its arrays may expand to
_MAX_HEADER = 10_000  # [bytes] numpy's own default limit for one .npy header
_NUMERIC_KINDS = frozenset("biuf")  # bool, signed, unsigned, float
MAX_T_S = 1e9  # [s] the largest |t|: 1e300 s passed as finite, then overflowed int64 nanoseconds
_MAX_ENTRY_BYTES = 1024  # [bytes] one member's central directory entry: 46, its name and extra fields (numpy: ~70)


class ReplayPolicy:
    """Replays the chunks of one ``.npz`` file, each cycle from its start."""

    def __init__(self, path: Path, dof: int):
        self.path = Path(path)
        self.source = f"replay:{path}"
        self.t, self.actions, self.uncertainty, dt = _load(self.path, dof)
        self.dt_ns = round(dt * 1e9)
        self._t_ns = np.round(self.t * 1e9).astype(np.int64)
        self._hash = hashlib.sha256(self.path.read_bytes()).hexdigest()
        self.reset()

    def reset(self) -> None:
        self._t0_ns: int | None = None
        self._next = 0
        self._last: ActionChunk | None = None

    def content_hash(self) -> str:
        return self._hash

    def infer(self, observation: Observation) -> ActionChunk:
        """The next recorded chunk whose time has come; the last one again while none has."""
        if self._t0_ns is None:
            self._t0_ns = observation.t_ns
        now = observation.t_ns - self._t0_ns
        if self._next < len(self.t) and (self._last is None or self._t_ns[self._next] <= now):
            i = self._next
            self._next += 1
            unc = None if self.uncertainty is None else self.uncertainty[i]
            stamp = min(self._t0_ns + int(self._t_ns[i]), observation.t_ns)
            self._last = ActionChunk(self.actions[i], stamp, self.dt_ns, unc)
        return self._last


def _load(path: Path, dof: int):
    where = f"replay file {path}"
    data = read_npz(path, where, ("t", "actions", "uncertainty", "dt"), ("t", "actions", "dt"))
    t, actions, unc, dt = data["t"], data["actions"], data.get("uncertainty"), data["dt"]
    for name, array in data.items():
        if array.dtype.kind == "b":  # dt = True was taken for 1 s
            raise ConfigError(f"{where}: {name} is of dtype bool; it holds numbers (int or float)")
    if t.ndim != 1 or len(t) == 0:
        raise ConfigError(f"{where}: t must be a non-empty 1-D array of finite seconds, got shape {t.shape}")
    beyond = np.flatnonzero(~(np.abs(t) <= MAX_T_S))  # NaN included
    if beyond.size:
        i = int(beyond[0])
        raise ConfigError(f"{where}: t must be finite seconds within +-{MAX_T_S:g} s (stamps in int64 ns), "
                          f"got t[{i}] = {t[i]}")
    if actions.ndim != 3 or actions.shape[0] != len(t) or actions.shape[1] == 0 or actions.shape[2] != dof:
        raise ConfigError(f"{where}: actions must have shape (N={len(t)}, H>0, D={dof}), got {actions.shape}")
    if unc is not None and unc.shape != actions.shape[:2]:
        raise ConfigError(f"{where}: uncertainty must have shape {actions.shape[:2]}, got {unc.shape}")
    if dt.shape != () or not 0.001 <= float(dt) <= 1.0:
        raise ConfigError(f"{where}: dt must be a scalar in [0.001, 1] s, got {dt.tolist()!r}")
    actions = actions.astype(np.float64)
    return t.astype(np.float64), actions, None if unc is None else unc.astype(np.float64), float(dt)


def read_npz(path: Path, where: str, allowed: tuple[str, ...], required: tuple[str, ...],
             max_bytes: int = MAX_BYTES) -> dict[str, np.ndarray]:
    """The numeric arrays of an ``.npz`` archive, bounded before anything is allocated.

    Each member's ``.npy`` header is read first: its dtype must be a plain number or bool (no
    object arrays, strings or records, so nothing is unpickled) and its declared shape, times its
    item size, must fit in what is left of ``max_bytes`` [bytes] and in the member's declared
    uncompressed size, which bounds decompression. Before that, the archive's directory may list no more members
    than ``allowed`` names, in no more bytes than they need. Anything else is one ConfigError naming it.
    """
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{where}: no such file")
    if not path.is_file():
        raise ConfigError(f"{where}: not a regular file")
    if path.stat().st_size > max_bytes:
        raise ConfigError(f"{where}: {path.stat().st_size} bytes is over the limit of {max_bytes} bytes")
    arrays: dict[str, np.ndarray] = {}
    budget = max_bytes
    try:
        _check_directory(path, where, len(allowed))
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                name = info.filename.removesuffix(".npy")
                if name not in allowed:
                    raise ConfigError(f"{where}: unknown array {name!r}; allowed: {', '.join(allowed)}")
                if name in arrays:
                    raise ConfigError(f"{where}: array {name!r} appears twice")
                if info.flag_bits & 0x1:  # zipfile raises a bare RuntimeError for an encrypted member
                    raise ConfigError(f"{where}: array {name!r} is encrypted; save the file with numpy.savez")
                if info.file_size > budget:
                    raise ConfigError(f"{where}: array {name!r} expands to {info.file_size} bytes, over the limit "
                                      f"of {max_bytes} bytes for the whole file")
                with archive.open(info) as member:
                    arrays[name] = _read_member(member, info.file_size, f"{where}: array {name!r}")
                budget -= info.file_size
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, NotImplementedError,
            UnicodeDecodeError) as exc:  # a member name flagged UTF-8 that is not
        raise ConfigError(f"{where}: not a readable .npz archive ({exc.__class__.__name__})") from None
    for key in required:
        if key not in arrays:
            raise ConfigError(f"{where}: missing array {key!r}; it has: {', '.join(arrays) or 'nothing'}")
    return arrays


def _check_directory(path: Path, where: str, most: int) -> None:
    """ConfigError if the archive's end record lists more than ``most`` members, or a directory bigger than they
    need: zipfile parses the whole directory before a member can be looked at (5 million entries in 255 MB took
    2.5 GB and 43 s to be refused). Not a zip archive: left to zipfile to say."""
    with open(path, "rb") as f:
        end = zipfile._EndRecData(f)  # noqa: SLF001 - the end record zipfile itself reads first, zip64 included
    if end is None:
        return
    count, size = end[zipfile._ECD_ENTRIES_TOTAL], end[zipfile._ECD_SIZE]  # noqa: SLF001
    if count > most or size > most * _MAX_ENTRY_BYTES:
        raise ConfigError(f"{where}: its directory lists {count} members in {size} bytes; it may hold at most "
                          f"{most} arrays")


def _read_member(member, declared: int, what: str) -> np.ndarray:
    try:
        version = np.lib.format.read_magic(member)
        read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                       (2, 0): np.lib.format.read_array_header_2_0}.get(version)
        if read_header is None:
            raise ConfigError(f"{what}: .npy format version {version} is not supported")
        shape, fortran, dtype = read_header(member, max_header_size=_MAX_HEADER)
    except (ValueError, TypeError, SyntaxError, EOFError) as exc:
        raise ConfigError(f"{what}: not a readable .npy array ({exc.__class__.__name__})") from None
    if dtype.kind not in _NUMERIC_KINDS or dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
        raise ConfigError(f"{what}: dtype {dtype.str!r} is not allowed; arrays hold numbers (int, float)")
    count = int(np.prod(shape, dtype=object))
    if count * dtype.itemsize > declared:
        raise ConfigError(f"{what}: its header declares shape {shape}, {count * dtype.itemsize} bytes, but the "
                          f"member holds at most {declared}")
    raw = member.read(count * dtype.itemsize)
    if len(raw) != count * dtype.itemsize:
        raise ConfigError(f"{what}: truncated: {len(raw)} of {count * dtype.itemsize} bytes")
    array = np.frombuffer(raw, dtype=dtype)
    return array.reshape(shape[::-1]).T if fortran else array.reshape(shape)


def make_replay_policy(arg: str, cell) -> ReplayPolicy:
    """``replay:FILE.npz`` for ``cell``."""
    if not arg:
        raise ConfigError("policy: 'replay' needs a file, e.g. 'replay:incident.npz'")
    return ReplayPolicy(Path(arg), cell.profile.dof)
