"""Reading a YAML input file (scenario, action map, profile): one loader for all, with its limits.

Every YAML document cellguard reads goes through ``parse_yaml``: PyYAML's safe loader (no Python
objects), plus what a careless or hostile file needs refused rather than guessed at. A key that
appears twice in one mapping (YAML's "the last wins" silently ran the other robot), nesting deeper
than ``MAX_DEPTH`` (a recursive alias included), a document whose aliases expand to more than
``MAX_VALUES`` values (a few hundred bytes of aliases expand to gigabytes once validated), a file
over ``MAX_BYTES`` (``/dev/zero`` is never read past the limit), and a path that is a FIFO or a
socket (refused before it is read: opening one waits for a writer) are each one error that names
the file and what is wrong. A merge key (``<<: *defaults``) merges as YAML 1.1 says: a mapping's own keys
override merged ones, and of ``<<: [*a, *b]`` the earlier mapping the later. A date is text, as it was written
(``measured: 2026-10-14`` is the string "2026-10-14"): PyYAML's timestamps made a ``datetime.date`` that JSON
cannot write, and an impossible date (``2026-02-30``) a ValueError in every reader; a field that must hold a date
checks the text.
A number in exponent form without a dot (``5e-1``, ``1e300``) is a number, as in YAML 1.2: PyYAML's
YAML 1.1 read it as the text "5e-1", which a number field then refused with a puzzling message.
A whole number is YAML 1.2's too: ``020`` is 20 (YAML 1.1 read it as octal 16, so ``production_cycles: 010`` ran 8
cycles), ``0o20`` is octal, ``0x1F`` hex, and ``1:05`` is text (YAML 1.1 read base 60, 65); ``_`` between two digits
is kept as a separator (``1_000``: it cannot be read as another number), anywhere else it makes text (``1_``,
``0x_1``). Digits are ASCII (``!!int ٣`` is refused, not 3). A boolean is YAML 1.2's too: only ``true`` and ``false``
(``True``, ``TRUE``, ``False``, ``FALSE``); YAML 1.1's ``yes``, ``no``, ``on``, ``off`` are text (``site: no`` was
False, a joint named ``on`` the key True); an explicit ``!!bool yes`` says what it means and is still true. A field
that wants a boolean and gets such a text says to write true or false (``yaml_bool_text``). ``dump_yaml`` writes what
this loader reads back as written: a text that it (or YAML 1.1) would read as something else is quoted
(``version: '09'``, ``name: 'no'``).
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path

import yaml

from cellguard.errors import ConfigError

MAX_BYTES = 1 << 20  # [bytes] the largest YAML input file; a scenario with 10,000 faults is about 600 kB
MAX_DEPTH = 32  # nested mappings and lists; cellguard's files use at most 5
MAX_VALUES = 1_000_000  # mappings, lists and scalars in the document with every alias expanded


class _Refused(yaml.YAMLError):
    """A document the loader refuses; the message says why and where."""


_TIMESTAMP = "tag:yaml.org,2002:timestamp"
_MERGE = "tag:yaml.org,2002:merge"
_MERGE_KEY = object()  # a merge key ``<<`` among a mapping's keys (a quoted '<<' is the text)
_FLOAT = "tag:yaml.org,2002:float"
_INT = "tag:yaml.org,2002:int"
_DIGITS = "[0-9]+(?:_[0-9]+)*"  # ASCII digits, ``_`` only between two of them
# YAML 1.1's floats less base 60, plus YAML 1.2's exponent form without a dot (``1e-3``) and sign before a leading dot
# (``-.5``: YAML 1.1 read text, and ``!!float -.5`` was -0.5); an integer stays an integer
_FLOAT_FORM = re.compile(rf"""^(?:[-+]?{_DIGITS}\.(?:{_DIGITS})?(?:[eE][-+]?[0-9]+)?
                    |[-+]?{_DIGITS}[eE][-+]?[0-9]+
                    |[-+]?\.{_DIGITS}(?:[eE][-+]?[0-9]+)?
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))\Z""", re.X)
# YAML 1.2's integers (decimal with leading zeros, 0o octal, 0x hex), with ``_`` separators between digits
_INT_FORM = re.compile(rf"^[-+]?(?:{_DIGITS}|0o[0-7]+(?:_[0-7]+)*|0x[0-9a-fA-F]+(?:_[0-9a-fA-F]+)*)\Z")
_DECIMAL_FORM = re.compile(rf"[-+]?{_DIGITS}\Z")  # what ``!!float`` takes besides a float's form (``!!float 5``)
_BOOL = "tag:yaml.org,2002:bool"
# YAML 1.1's booleans, any case (``y`` and ``n`` too: PyYAML left them text, other YAML 1.1 readers do not): what
# ``!!bool`` takes, what ``dump_yaml`` quotes, what a boolean field written as text is told to write as true or false
_BOOL_FORM = re.compile(r"(?:y|n|yes|no|true|false|on|off)\Z", re.I)
_TRUE_TEXTS = ("y", "yes", "true", "on")
_CORE_BOOL_FORM = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)\Z")  # YAML 1.2 core schema's booleans
_YAML12_FORMS = {_FLOAT: _FLOAT_FORM, _INT: _INT_FORM, _BOOL: _CORE_BOOL_FORM}  # what a plain scalar must be to be one


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys and deep nesting while it composes, reads dates as text and numbers and
    booleans as YAML 1.2 does."""

    yaml_implicit_resolvers = {first: [(tag, _YAML12_FORMS.get(tag, regexp)) for tag, regexp in resolvers
                                       if tag != _TIMESTAMP]
                               for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}

    def compose_node(self, parent, index):
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise _Refused(f"line {mark.line + 1}: nested deeper than {MAX_DEPTH} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def flatten_mapping(self, node):
        """Merge into ``node`` the mappings its merge key ``<<`` names (YAML 1.1's merge key): its own keys override
        merged ones, and of a list ``<<: [*a, *b]`` the earlier mapping overrides the later. A key written twice in
        ``node`` (``<<`` too) is refused first. PyYAML's own merge told keys apart by object identity, so the later
        mapping of a list won for a long key and the earlier for a one-letter one, and a node merged twice kept a key
        that its own had overridden."""
        done, busy = self.__dict__.setdefault("_merged", set()), self.__dict__.setdefault("_merging", set())
        if id(node) in done:
            return
        if id(node) in busy:
            raise _Refused(f"line {node.start_mark.line + 1}: a mapping merges itself (<< names its own anchor)")
        busy.add(id(node))
        own, sources, seen = [], [], set()
        for key_node, value_node in node.value:
            merge = key_node.tag == _MERGE
            key = _MERGE_KEY if merge else self.construct_object(key_node, deep=True)
            if _taken(key, seen):
                raise _Refused(f"line {key_node.start_mark.line + 1}: key {'<<' if merge else key!r} appears twice "
                               f"in one mapping{'; merge several with <<: [*a, *b]' if merge else ''}")
            if not merge:
                own.append((key_node, value_node))
                continue
            sources = value_node.value if isinstance(value_node, yaml.SequenceNode) else [value_node]
            if not all(isinstance(source, yaml.MappingNode) for source in sources):
                raise yaml.constructor.ConstructorError(  # at the ``<<``: an alias's mark is its anchor's
                    "while constructing a mapping", node.start_mark,
                    "expected a mapping or list of mappings for merging", key_node.start_mark)
        merged = []
        for source in sources:
            self.flatten_mapping(source)
            merged += [pair for pair in source.value if not _taken(self.construct_object(pair[0], deep=True), seen)]
        copied = self.__dict__.get("_copied", 0) + len(merged)  # each merge copies its pairs: counted as they go
        if copied > MAX_VALUES:  # (a chain of merges copied quadratically many, a doubling one exponentially)
            raise _Refused(f"line {node.start_mark.line + 1}: merge keys copy more than {MAX_VALUES} keys")
        self._copied = copied
        node.value = merged + own
        busy.discard(id(node))
        done.add(id(node))


def _taken(key, seen: set) -> bool:
    """Whether ``key`` is in ``seen``; it is added if not. An unhashable key never is: PyYAML refuses it, naming it."""
    try:
        if key in seen:
            return True
        seen.add(key)
    except TypeError:
        pass
    return False


def _construct_int(loader, node) -> int:
    """An integer read as YAML 1.2 reads it (``!!int 010`` included): decimal unless ``0o`` or ``0x`` says otherwise."""
    text = _explicit(loader, node, "a whole number (digits, 0o octal or 0x hex)", _INT_FORM).replace("_", "")
    return int(text, {"0o": 8, "0x": 16}.get(text.lstrip("+-")[:2], 10))


def _construct_float(loader, node) -> float:
    """A float as YAML 1.1 reads it, less base 60 (``!!float 1:30`` was 90.0); a decimal whole number too."""
    _explicit(loader, node, "a number", _FLOAT_FORM, _DECIMAL_FORM)
    return loader.construct_yaml_float(node)


def _explicit(loader, node, what: str, *forms: re.Pattern) -> str:
    """The text of ``node``, which one of ``forms`` matches: a value only YAML 1.1 read (``!!int 0b11``, ``!!float
    1:30``) or none (``!!int 1e3``) is refused in one line naming it, not with Python's ``int()`` message."""
    text = loader.construct_scalar(node)
    if not any(form.match(text) for form in forms):
        raise _Refused(f"line {node.start_mark.line + 1}: !!{node.tag.rpartition(':')[2]} {text!r} is not {what}")
    return text


def _construct_bool(loader, node) -> bool:
    """A bool as YAML 1.1 reads it (``!!bool yes``); ``!!bool abc`` is refused naming it (PyYAML's KeyError was a
    traceback)."""
    return _explicit(loader, node, "true or false", _BOOL_FORM).lower() in _TRUE_TEXTS


# an explicit ``!!timestamp`` is text too
_StrictLoader.add_constructor(_TIMESTAMP, lambda loader, node: loader.construct_scalar(node))
_StrictLoader.add_constructor(_INT, _construct_int)
_StrictLoader.add_constructor(_FLOAT, _construct_float)
_StrictLoader.add_constructor(_BOOL, _construct_bool)


def yaml_bool_text(value: object) -> bool:
    """``value`` is a text that YAML 1.1 read as a boolean (``yes``, ``off``) or a quoted ``"true"``: what a field
    wanting a boolean then got, so its error can say to write true or false."""
    return isinstance(value, str) and _BOOL_FORM.match(value) is not None


class _Dumper(yaml.SafeDumper):
    """SafeDumper that quotes a text that the loader or YAML 1.1 reads as something else (``'09'``, ``'0o17'``,
    ``'1e3'``, ``'2026-11-01'``, ``'no'``, ``'y'``): YAML 1.1's rules alone left ``09`` plain, which the loader reads
    as the number 9."""

    yaml_implicit_resolvers = {first: _StrictLoader.yaml_implicit_resolvers.get(first, [])
                               + yaml.SafeDumper.yaml_implicit_resolvers.get(first, [])
                               + ([(_BOOL, _BOOL_FORM)] if first in set("yYnNtTfFoO") else [])
                               for first in {**_StrictLoader.yaml_implicit_resolvers,
                                             **yaml.SafeDumper.yaml_implicit_resolvers}}


def _represent_str(dumper, text: str):
    """A text with a NEL (U+0085) double-quoted, where it is written escaped: PyYAML wrote it raw in a quoted or plain
    text, which reads it back as a line break folded to a space."""
    return dumper.represent_scalar("tag:yaml.org,2002:str", text, style='"' if "\x85" in text else None)


_Dumper.add_representer(str, _represent_str)


def dump_yaml(document: object) -> str:
    """``document`` as YAML text that ``parse_yaml`` reads back equal (keys in their order, Unicode as written)."""
    return yaml.dump(document, Dumper=_Dumper, sort_keys=False, allow_unicode=True)


def parse_yaml(data: bytes | str, where: str, error: type[ConfigError] = ConfigError) -> object:
    """The decoded document in ``data`` (from ``where``, a file name or a description); raises ``error``."""
    if len(data) > MAX_BYTES:
        raise error(f"{where}: larger than the limit of {MAX_BYTES} bytes")
    try:
        document = yaml.load(data, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass
        _check_expanded(document)
        return document
    except _Refused as exc:
        raise error(f"{where}: {exc}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f" at line {mark.line + 1}" if mark is not None else ""
        raise error(f"{where}: not valid YAML{line} ({exc.problem or exc.__class__.__name__})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise error(f"{where}: not valid YAML ({exc.__class__.__name__})") from None
    except ValueError as exc:  # a whole number over the digits Python converts (4300)
        raise error(f"{where}: not valid YAML ({exc})") from None
    except RecursionError:
        raise error(f"{where}: nested too deeply to read") from None


def _check_expanded(document: object) -> None:
    """Refuse a document that, with its aliases expanded, is deeper than MAX_DEPTH or has over MAX_VALUES values."""
    stack, count = [(document, 1)], 0
    while stack:
        value, depth = stack.pop()
        count += 1
        if count > MAX_VALUES:
            raise _Refused(f"expands to more than {MAX_VALUES} values (through aliases)")
        if depth > MAX_DEPTH:
            raise _Refused(f"nested deeper than {MAX_DEPTH} levels (through aliases)")
        if isinstance(value, dict):
            stack.extend((item, depth + 1) for item in value.values())
        elif isinstance(value, list):
            stack.extend((item, depth + 1) for item in value)


def read_bounded(path: Path, what: str, error: type[ConfigError] = ConfigError, limit: int = MAX_BYTES) -> bytes:
    """The bytes of ``path`` (a ``what`` file), reading at most ``limit`` bytes: larger is refused.

    Opened without blocking and checked before it is read: a FIFO or a socket is refused (opening
    a FIFO for reading waits for a writer that may never come), a folder is refused, a link to
    nothing is named as such. A device is read up to the limit (``/dev/zero`` is refused as too large).
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        if path.is_symlink():
            raise error(f"{path}: is a link to nothing, not a {what} file") from None
        raise error(f"{path}: no such {what} file") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, not a {what} file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} file ({exc.strerror or exc.__class__.__name__})") from None
    return read_opened(fd, path, what, error, limit)


def read_opened(fd: int, path: Path, what: str, error: type[ConfigError] = ConfigError, limit: int = MAX_BYTES
                ) -> bytes:
    """The bytes of the file open as ``fd`` (opened without blocking; named ``path``, a ``what`` file), at most
    ``limit``: a folder, a FIFO or a socket refused, larger refused; ``fd`` is closed. For a caller that opens the
    file its own way (without following a link: a check of the path before the open can be raced)."""
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise error(f"{path}: is a folder, not a {what} file")
        if stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode):
            raise error(f"{path}: is a {'FIFO' if stat.S_ISFIFO(mode) else 'socket'}, not a regular {what} file")
        os.set_blocking(fd, True)  # a regular file or a device: read as usual, bounded below
        with os.fdopen(fd, "rb") as f:
            fd = -1
            data = f.read(limit + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} file ({exc.strerror or exc.__class__.__name__})") from None
    finally:
        if fd >= 0:
            os.close(fd)
    if len(data) > limit:
        raise error(f"{path}: the {what} file is larger than the limit of {limit} bytes")
    return data


def read_yaml(path: Path, what: str, error: type[ConfigError] = ConfigError) -> object:
    """The decoded document of ``path`` (a ``what``, e.g. "scenario"); raises ``error`` naming the file."""
    return parse_yaml(read_bounded(path, what, error), str(path), error)


def reject_unknown_keys(mapping: Mapping, allowed: Iterable[str], prefix: str,
                        error: type[ConfigError] = ConfigError) -> None:
    """Raise ``error`` naming the first key of ``mapping`` not in ``allowed``, as ``<prefix><key>``."""
    allowed = list(allowed)
    for key in mapping:
        if key not in allowed:
            raise error(f"{prefix}{key}: unknown key; allowed: {', '.join(allowed)}")
