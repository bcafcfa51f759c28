"""Where a command may write its output: never over a record, nor into a run folder, nor over its own inputs,
nor over any file but one of its own kind (a page over a page).

Every command that writes an output (export, to-lerobot, recover, report, replay, identify --write,
train-demo-policy) asks here first, before it reads or computes anything, so a mistyped ``-o`` cannot
cost a record, an input file or minutes of work.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from fnmatch import fnmatch
from pathlib import Path
from typing import BinaryIO

from cellguard.errors import RecordError
from cellguard.output import never_replaced, not_regular
from cellguard.record.reader import record_file
from cellguard.record.writer import RECORD_FILE


@dataclass(frozen=True)
class OwnKind:
    """A kind of file a command writes and replaces: ``what`` names it in a refusal; ``ours(f)`` tells, from the bytes
    of ``f`` (open for reading, at its start), whether cellguard wrote it."""

    what: str
    ours: Callable[[BinaryIO], bool]
    hint: str = ""  # said after a refusal: how an earlier file of this kind may fail ``ours``


def starts_with(head: bytes) -> Callable[[BinaryIO], bool]:
    """``OwnKind.ours`` for a kind told by the bytes its files begin with."""
    return lambda f: f.read(len(head)) == head


# how every page cellguard renders (report, replay, release) has begun since the first: older pages are its own too
PAGE_HEAD = b"<!doctype html><html lang=en><head><meta charset=utf-8><title>cellguard "
PAGE = OwnKind("an HTML page", starts_with(PAGE_HEAD))


def refuse_output(output: Path, source: Path | None, to_folder: bool = False, *,
                  inputs: Iterable[tuple[str, Path | None]] = (), option: str = "-o", replace: bool = True,
                  own: tuple[str, ...] = (), kind: OwnKind | None = None) -> None:
    """RecordError unless ``output`` may be written: nothing recorded, and nothing the command reads, is ever
    overwritten.

    Refused, after following links: the record being read (``source``, a run folder or an .mcap file,
    whatever its bytes hold; None: the command reads no record), any other file the command reads
    (``inputs``: (what, path) pairs such as ("--profile file", path); None paths are skipped), a file that
    starts with the MCAP magic or the SQLite magic (a store), and a run folder (one holding record.mcap) or
    anything in it, since its summary, index and baseline belong to the record; ``own`` names (glob patterns,
    e.g. ``replay-cycle-*.html``) of the pages a command writes directly in ``source``'s own run folder are the
    exception. Also refused: a device, FIFO or socket (a rename would replace the node itself), a file where a
    folder must be (the output itself with ``to_folder``, or a parent), a folder where a file must be, and an
    existing file unless ``replace``, and with ``kind`` one that is neither empty nor of that kind as cellguard
    wrote it. ``option`` is how the message names the output (``-o``, ``--write``).
    """
    name = f"{option} {output}"
    try:
        target = Path(output).resolve()
        if source is not None and target == record_file(source).resolve():
            raise RecordError(f"{name}: is the record being read; cellguard never overwrites a record; "
                              f"choose another path")
        for what, path in inputs:
            if path is not None and target == Path(path).resolve():
                raise RecordError(f"{name}: is the {what} being read; choose another path")
        run = next((d for d in (target, *target.parents) if (d / RECORD_FILE).exists()), None)
        if run is not None and not _own_page(target, run, source, own):
            where = "is a run folder" if run == target else f"is in the run folder {run}"
            raise RecordError(f"{name}: {where}, which holds a record; cellguard never overwrites a record "
                              f"or its run folder; choose a path outside it")
        kept = never_replaced(target) if target.is_file() else None
        if kept is not None:
            raise RecordError(f"{name}: is {kept}; cellguard never overwrites a record or a store; choose another "
                              f"path")
        node = not_regular(Path(output))  # stat follows the link itself: /proc/self/fd/1 of a pipe resolves to no name
        parent = next((d for d in target.parents if d.exists()), None)
        blocked = parent is not None and not parent.is_dir()
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop
        raise RecordError(f"{name}: cannot be checked ({getattr(exc, 'strerror', None) or exc})") from None
    if blocked:
        raise RecordError(f"{name}: {parent} is a file, not a folder; choose another path")
    if node is not None:
        raise RecordError(f"{name}: is {node}, not a regular file; cellguard writes only regular files: "
                          f"choose another path")
    if to_folder and target.exists() and not target.is_dir():
        raise RecordError(f"{name}: is a file; give a new folder")
    if not to_folder and target.is_dir():
        raise RecordError(f"{name}: is a folder; name a file to write")
    if not replace and target.exists():
        raise RecordError(f"{name}: already exists; choose another path or give --overwrite to replace it")
    if kind is not None:
        _refuse_other_kind(Path(output), kind, name)


def _refuse_other_kind(output: Path, kind: OwnKind, name: str) -> None:
    """RecordError unless ``output`` is new, empty or ``kind`` as cellguard wrote it: no list of inputs names every
    file a user may type after ``-o`` (a release's frozen policy, a site's release plan, a calibrated profile and its
    MJCF were each replaced by a page, exit 0)."""
    try:
        with open(output, "rb") as f:
            empty = not f.read(1)
            f.seek(0)
            mine = empty or kind.ours(f)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise RecordError(f"{name}: cannot be read to tell whether cellguard wrote it ({exc.strerror or exc}); "
                          "choose another path") from None
    if not mine:
        raise RecordError(f"{name}: exists and is not {kind.what} cellguard wrote; cellguard replaces only its own "
                          f"(or an empty file): choose another path, or remove the file first{kind.hint}")


def _own_page(target: Path, run: Path, source: Path | None, own: tuple[str, ...]) -> bool:
    """Whether ``target`` is one of the command's own pages, directly in the run folder of the record it reads."""
    if source is None or not own or target.parent != run:
        return False
    return run == record_file(source).resolve().parent and any(fnmatch(target.name, p) for p in own)
