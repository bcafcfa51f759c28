"""The ``cellguard`` console script. Plugins are discovered while cellguard is imported (the scenario schema is
built from the kinds found), before any command can catch an error: a broken plugin module ended every command,
``--help`` included, in a traceback. Here it ends in one line naming the file, exit 2, as bad input does."""

from __future__ import annotations

import sys

from cellguard.plugins import PluginError
from cellguard.printable import printable


def main() -> None:
    """Run the command line; a PluginError, on import or from a command importing plugins later: one line, exit 2."""
    try:
        from cellguard.cli import app

        app()
    except PluginError as exc:
        sys.stderr.write(f"error: {printable(exc)}\n")
        sys.exit(2)
