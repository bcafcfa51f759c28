"""cellguard: adapt, guard, record and diagnose a robot policy on an installed robot."""

from cellguard.errors import CellguardError

__version__ = "0.1.0"
__all__ = ["CellguardError", "__version__"]
