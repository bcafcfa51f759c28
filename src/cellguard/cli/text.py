"""Text from files, records and servers, made safe to print on a technician's terminal.

A record's ``site:``, a key in a hostile YAML file or a server's error can hold terminal escape
codes (which recolour, retitle or clear the screen) and line breaks (which turn one error line
into several). Everything the CLI prints from such sources goes through ``printable``: control
characters are shown as escapes (``\\x1b``, ``\\n``), the rest is unchanged.
"""

from __future__ import annotations

import sys

from cellguard.printable import printable


def printable_tree(value):
    """``value`` (dicts, lists, strings, numbers) with ``printable`` applied to every string in it."""
    if isinstance(value, str):
        return printable(value)
    if isinstance(value, dict):
        return {printable_tree(k): printable_tree(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(printable_tree(v) for v in value)
    return value


def say(text: str, err: bool = True) -> None:
    """One line on stderr (or stdout) as written: paths and record text are the user's, so no markup, and
    control characters escaped (a file named ``rep[/].html`` or holding an escape code prints as it is)."""
    (sys.stderr if err else sys.stdout).write(printable(text) + "\n")
