"""Errors of the release path; all are bad input (the CLI prints one line and exits 2).

    ConfigError
    └── ReleaseError        a release command that cannot be carried out; no pointer moved
        ├── BundleMismatch  a bundle whose inputs changed since ``release create`` (hash mismatch)
        ├── StageError      a promotion that skips a stage or lacks passed gates; an unknown stage
        └── GateError       a gate file with an unknown metric, key or impossible value
"""

from __future__ import annotations

from cellguard.errors import ConfigError


class ReleaseError(ConfigError):
    """A release command refused; nothing in the store changed."""


class BundleMismatch(ReleaseError):
    """A frozen input (policy, action map, profile) no longer hashes to what the manifest says."""


class StageError(ReleaseError):
    """A promotion out of order, or without the previous stage's gates passed."""


class GateError(ReleaseError):
    """A gate declaration that cannot be evaluated."""
