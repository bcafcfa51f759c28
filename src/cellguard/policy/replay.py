"""``policy: replay:FILE.npz``: recorded chunks played back, to reproduce an incident or test a stream.

The file holds ``t`` (N,) [s], when each chunk's observation was taken, counted from the start
of the cycle; ``actions`` (N, H, D) in the cell's joint order and SI units; optionally
``uncertainty`` (N, H) and ``dt`` (a scalar [s], the step of every chunk; 0.02 s if absent).
Each cycle replays the file from its start. Records are handed out in file order once their
time has come, stamped with that time, so late, out-of-order and silent streams replay as
recorded; the values are not checked here (NaN and wrong sizes are what such streams are for):
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

DEFAULT_DT_S = 0.02


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
            self._last = ActionChunk(self.actions[i], self._t0_ns + int(self._t_ns[i]), self.dt_ns, unc)
        return self._last


def _load(path: Path, dof: int):
    where = f"replay file {path}"
    try:
        data = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ConfigError(f"{where}: no such file") from None
    except (ValueError, OSError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"{where}: not a readable .npz archive ({exc.__class__.__name__})") from None
    with data:
        for key in ("t", "actions"):
            if key not in data.files:
                raise ConfigError(f"{where}: missing array {key!r}; it has: {', '.join(data.files) or 'nothing'}")
        unknown = set(data.files) - {"t", "actions", "uncertainty", "dt"}
        if unknown:
            raise ConfigError(f"{where}: unknown array(s) {', '.join(sorted(unknown))}; "
                              f"allowed: t, actions, uncertainty, dt")
        t, actions = np.asarray(data["t"]), np.asarray(data["actions"])
        unc = np.asarray(data["uncertainty"]) if "uncertainty" in data.files else None
        dt = np.asarray(data["dt"]) if "dt" in data.files else np.asarray(DEFAULT_DT_S)
    if t.ndim != 1 or len(t) == 0 or not np.issubdtype(t.dtype, np.number) or not np.isfinite(t).all():
        raise ConfigError(f"{where}: t must be a non-empty 1-D array of finite seconds, got shape {t.shape}")
    if actions.ndim != 3 or actions.shape[0] != len(t) or actions.shape[1] == 0 or actions.shape[2] != dof:
        raise ConfigError(f"{where}: actions must have shape (N={len(t)}, H>0, D={dof}), got {actions.shape}")
    if not np.issubdtype(actions.dtype, np.number):
        raise ConfigError(f"{where}: actions must be numbers, got dtype {actions.dtype}")
    if unc is not None and unc.shape != actions.shape[:2]:
        raise ConfigError(f"{where}: uncertainty must have shape {actions.shape[:2]}, got {unc.shape}")
    if dt.shape != () or not np.issubdtype(dt.dtype, np.number) or not 0.001 <= float(dt) <= 1.0:
        raise ConfigError(f"{where}: dt must be a scalar in [0.001, 1] s, got {dt.tolist()!r}")
    actions = actions.astype(np.float64)
    return t.astype(np.float64), actions, None if unc is None else unc.astype(np.float64), float(dt)


def make_replay_policy(arg: str, cell) -> ReplayPolicy:
    """``replay:FILE.npz`` for ``cell``."""
    if not arg:
        raise ConfigError("policy: 'replay' needs a file, e.g. 'replay:incident.npz'")
    return ReplayPolicy(Path(arg), cell.profile.dof)
