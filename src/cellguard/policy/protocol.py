"""The Policy protocol: every source (scripted, replay, lerobot, openpi, onnx) implements it."""

from __future__ import annotations

from typing import Protocol

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
