"""Text from files, records, servers and plugins as one printable line: control and format characters written as
their escapes (``\\x1b``, ``\\n``), the rest unchanged. A leaf, so that ``cellguard.entry`` can use it before the
command line (whose import runs the plugins' discovery) is imported; ``cli.text`` prints with it."""

from __future__ import annotations

import unicodedata


def printable(text: object) -> str:
    """``text`` as a string with every control or format character written as its escape."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() or (ch == " ") else _escape(ch) for ch in text)


def _escape(ch: str) -> str:
    if unicodedata.category(ch) == "Zs":  # a space of another width: harmless, keep it
        return ch
    return ch.encode("unicode_escape").decode("ascii")
