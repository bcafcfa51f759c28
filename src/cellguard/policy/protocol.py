"""The Policy protocol: every source (scripted, replay, lerobot, openpi, onnx) implements it."""

from __future__ import annotations

import hashlib
import inspect
from typing import Protocol

import numpy as np

from cellguard.policy.chunk import ActionChunk
from cellguard.robot.state import Observation


class Policy(Protocol):
    """Maps an observation to an action chunk. Runs off the servo path; may be slow."""

    source: str  # e.g. "scripted", "replay:incident.npz"; recorded in the context

    def reset(self) -> None:
        """Start a new episode (a cycle of the cell)."""

    def infer(self, observation: Observation) -> ActionChunk:
        """A chunk answering ``observation``, stamped with ``observation.t_ns``."""

    def content_hash(self) -> str:
        """A hash of what determines the policy's behaviour (weights, program, file)."""

    def close(self) -> None:
        """Release what the policy holds open (a connection, a session); the loop calls it once at
        the end. Sources that hold nothing inherit this no-op by subclassing ``Policy``."""


def behaviour_hash(policy, *values) -> str:
    """sha256 of everything that determines a coded policy's behaviour: the whole source of the module
    that defines its class (constants and helpers included, not just the class) and ``values``, its
    constructor parameters, calibration and taught data (arrays by dtype, shape and bytes; model files
    as bytes)."""
    digest = hashlib.sha256(inspect.getsource(inspect.getmodule(type(policy))).encode())
    for value in values:
        if isinstance(value, np.ndarray):
            digest.update(f"{value.dtype}{value.shape}".encode() + np.ascontiguousarray(value).tobytes())
        else:
            digest.update(value if isinstance(value, bytes) else repr(value).encode())
        digest.update(b"\0")
    return digest.hexdigest()
