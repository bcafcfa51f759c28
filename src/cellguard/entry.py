"""The ``cellguard`` console script. Plugins are discovered while cellguard is imported (the scenario schema is
built from the kinds found), before any command can catch an error: a broken plugin module ended every command,
``--help`` included, in a traceback. Here it ends in one line naming the file, exit 2, as bad input does. So does a
usage error (an option's value of the wrong type or out of its range, an unknown option, a missing argument): the
command line's own parser drew it in a box of four to six lines. An argument that starts with ``-`` (SQL opening with
a ``--`` comment) is read as an option: where it cannot be one, the line says to give it after ``--``. The parser
prints ``cellguard --help`` (and a bare ``cellguard``'s help) before any command's guard of stdout is set, so the
guard is set here: a full stdout was a traceback, a closed one exit 0."""

from __future__ import annotations

import json
import re
import sys

import typer

from cellguard.plugins import PluginError
from cellguard.printable import printable

# the parser's error class: click's, or typer's own copy of click (typer 0.2x bundles one), both BadParameter's base
USAGE_ERROR = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")
OPTION_NAME = re.compile(r"--?[^\W_][\w-]*")  # what an option can be called; "-- a comment\nSELECT 1" cannot


def main() -> None:
    """Run the command line; a PluginError, on import or from a command importing plugins later, and a usage error:
    one line, exit 2."""
    try:
        from cellguard.cli import app, stdout

        stdout.guard()  # the root's --help is printed before any command runs
        code = app(standalone_mode=False)  # a command's typer.Exit comes back as its code
    except PluginError as exc:
        sys.stderr.write(f"error: {printable(exc)}\n")
        sys.exit(2)
    except USAGE_ERROR as exc:
        said = exc.format_message()
        if not said:  # a group called bare: its help is on stdout already
            sys.exit(exc.exit_code)
        context = getattr(exc, "ctx", None)
        usage = context.command_path if context is not None else "cellguard"  # an option's missing value has none
        sys.stderr.write(f"error: {printable(_not_an_option(exc) or said)} (`{usage} --help` says how)\n")
        sys.exit(exc.exit_code)
    except typer.Abort:  # end of input at a prompt
        sys.stderr.write("error: aborted\n")
        sys.exit(1)
    sys.exit(code if isinstance(code, int) and not isinstance(code, bool) else 0)


def _not_an_option(exc) -> str | None:
    """For an unknown option that no option could be called (a space, a line break or a quote in what was typed, or
    a name that is not OPTION_NAME): it is an argument starting with ``-``, and what to do with it; None for any
    other usage error (``--bogus``, ``--timout=5``: click's own line, with its suggestion)."""
    name = getattr(exc, "option_name", None) if type(exc).__name__ == "NoSuchOption" else None
    if name is None:
        return None
    given = _typed(name, getattr(exc, "ctx", None))
    if OPTION_NAME.fullmatch(given.split("=", 1)[0]) and not re.search(r"[\s'\"]", given):
        return None
    return (f"{json.dumps(given, ensure_ascii=False)} is read as an option (it starts with '-'); give an argument "
            f"that starts with '-' after '--', every option before that")


def _typed(name: str, context) -> str:
    """The argument as typed that the parser read as the unknown option ``name`` (it cuts one at "=" or after a
    letter): the first that starts with it and is not the value of an option before it (``--out "- out"``)."""
    command = getattr(context, "command", None)
    valued = {opt for param in getattr(command, "params", ()) if not getattr(param, "is_flag", True)
              and getattr(param, "param_type_name", "") == "option" for opt in param.opts}
    args = sys.argv[1:]
    return next((arg for i, arg in enumerate(args) if arg.startswith(name) and not (i and args[i - 1] in valued)),
                name)
