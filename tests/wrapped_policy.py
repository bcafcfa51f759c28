"""Shared by the runtime tests: the scripted arm policy, wrapped, so a test's subclass changes what ``infer`` answers
(fails, stalls, a chunk the guard refuses) while the policy's identity and reset stay the scripted one's."""

from __future__ import annotations

from cellguard.policy.registry import make_policy
from cellguard.robot.registry import make_cell


class WrappedScripted:
    source = "test:wrapped"

    def __init__(self):
        self.inner, self.calls = make_policy("scripted", make_cell("arm-pick-place")), 0

    def content_hash(self) -> str:
        return self.inner.content_hash()

    def reset(self) -> None:
        self.inner.reset()
