"""Policy protocol, sources (scripted, replay, adapters) and the action map."""

from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy

__all__ = ["ActionChunk", "Policy"]
