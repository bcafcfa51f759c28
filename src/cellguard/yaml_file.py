"""Reading a YAML input file: a missing or malformed file, or an unknown key, is one error that names it."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import yaml

from cellguard.errors import ConfigError


def read_yaml(path: Path, what: str, error: type[ConfigError] = ConfigError) -> object:
    """The decoded document of ``path`` (a ``what``, e.g. "scenario"); raises ``error`` naming the file."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise error(f"{path}: no such {what} file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read the {what} file ({exc.__class__.__name__})") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({exc.__class__.__name__})") from None


def reject_unknown_keys(mapping: Mapping, allowed: Iterable[str], prefix: str,
                        error: type[ConfigError] = ConfigError) -> None:
    """Raise ``error`` naming the first key of ``mapping`` not in ``allowed``, as ``<prefix><key>``."""
    allowed = list(allowed)
    for key in mapping:
        if key not in allowed:
            raise error(f"{prefix}{key}: unknown key; allowed: {', '.join(allowed)}")
