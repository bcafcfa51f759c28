"""The one exception root of cellguard and its subclasses.

    CellguardError
    ├── ConfigError          bad input in a file or argument (profile, scenario, action map)
    │   ├── ProfileError     an embodiment profile that disagrees with its model
    │   ├── ScenarioError    a scenario file with an unknown key, wrong type or impossible value
    │   └── ExtraMissing     a built-in cell whose optional package is not installed (the SO-101's model)
    ├── UnknownNameError     a registry lookup that failed; lists the names that exist
    ├── RecordError          a record that cannot be written or read
    ├── OutputError          another output file or folder that cannot be written
    └── OperatorStopped      Ctrl-C/SIGTERM/SIGHUP ended work that runs cycles (exit 130, not 2)

Subclasses that belong to one part live beside its code: under ``ConfigError`` the release's
``ReleaseError`` (``BundleMismatch``, ``StageError``, ``GateError``), ``CalibrationError``,
``StartupRefused``, the policy's ``StepPeriodUnstated``, the fleet's ``SignatureError``, ``PolicyError`` and
``AuditError``; under ``RecordError`` the diagnosis's ``TooFewCycles``; under
``CellguardError`` the robot's ``RobotLinkError`` and ``BridgeError``, the policy's ``WireError`` and
``InferenceError``, the fleet's ``RefusedAggregate`` and ``StoreError`` (``StoreUnavailable``), and
``plugins.PluginError`` (a plugin module that cannot be imported or takes a name twice).

Every message names the field (or file) and what was allowed, in one line, so that the CLI
can print it and exit 2 without a traceback.
"""

from __future__ import annotations


class CellguardError(Exception):
    """Root of every error cellguard raises on purpose."""


class ConfigError(CellguardError, ValueError):
    """Bad input: the message names the field and the allowed range."""


class ProfileError(ConfigError):
    """An embodiment profile that disagrees with its MuJoCo model."""


class ScenarioError(ConfigError):
    """A scenario file that cannot run."""


class ExtraMissing(ConfigError):
    """A built-in cell needs ``cellguard[extra]``, not installed here: not bad input where it is installed
    (``release verify`` says such a release not checked here, as for a plugin's cell; a policy source's extra it
    finds by cellguard's own metadata)."""

    def __init__(self, extra: str, message: str):
        self.extra = extra
        super().__init__(message)

    def __reduce__(self):  # both arguments: a worker process's error crosses back whole, not as a TypeError
        return type(self), (self.extra, str(self))


class UnknownNameError(CellguardError, KeyError):
    """A name that is not registered; the message lists the names that are."""

    def __init__(self, kind: str, name: str, known: list[str] | tuple[str, ...]):
        self.kind, self.name, self.known = kind, name, tuple(known)
        super().__init__(f"unknown {kind} {name!r}; known: {', '.join(sorted(known))}")

    def __str__(self) -> str:  # KeyError would quote the whole message
        return self.args[0]


class RecordError(CellguardError):
    """A fault record that cannot be written or read."""


class OutputError(CellguardError):
    """An output file or folder (report, summary, model) that cannot be written."""


class OperatorStopped(CellguardError):
    """The operator stopped a command that runs cycles (a release stage): its record is complete, the rest was
    not done."""
