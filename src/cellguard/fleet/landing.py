"""A batch's lake files, landed as the store commits the batch, so the lake gets what the store took.

They are written under staged names (``NAME.TOKEN.staged``, which no reader lists) before the store commits
the batch, renamed into place only once the commit succeeded, and removed if the store refused it. Files a push
left staged (the server lost mid-commit, the push killed, a rename that failed) are brought to what the store
holds by the next push that reaches it (``reconcile``): the store's own rows of their signatures are landed, so a
file half published (its effects moved, its signatures not) loses nothing the store holds. Each staged file is
written under a name no reconcile lists (``.writing``) and ``flock``ed before it is renamed to its staged name:
a reconcile leaves a live push's files alone. Where the filesystem offers no locks, a live push's files cannot
be told from a dead one's: they are left, and named.
"""

from __future__ import annotations

import fcntl
import os
import secrets
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from cellguard.errors import OutputError
from cellguard.fleet.lake import (EFFECTS, NO_LOCKS, SIGNATURES, STAGED, effects_of, lake_file, lock_left,
                                  partition_files, read_table, refuse_links, row_value, staged_files, take_out,
                                  write_file)
from cellguard.output import UNLOCKABLE, make_folder

WRITING = ".writing"  # a staged file being written: no reconcile lists it


class Unpublished(OutputError):
    """The store took a batch but its staged lake files could not all be made visible; ``taken``: the store's
    (rows new or changed, rows already there), set by the store."""

    taken: tuple[int, int] = (0, 0)


class Landing:
    """A batch's lake files, written under staged names before the store commits the batch, each signatures file
    ``flock``ed by this process: ``publish`` makes them visible once the commit succeeded, ``discard`` removes them
    when the store refused it. ``release`` leaves them (the commit's outcome is not known: the server was lost, the
    push stopped) for ``reconcile`` to bring to what the store holds; a killed push leaves them the same way."""

    def __init__(self) -> None:
        self.parts: list[tuple[Path, Path, list[str], int | None]] = []  # (staged signatures, final, ids, lock)
        self.new = 0  # signatures not in the lake before

    def publish(self) -> int:
        """Rename each staged pair into place (effects first: an effect alone is never read), then take its
        signatures out of the partition's other files. Returns the signatures new to the lake."""
        try:
            for staged, target, ids, _ in self.parts:
                os.replace(effects_of(staged), effects_of(target))
                os.replace(staged, target)
                others = [(o, read_table(o)) for o in partition_files(target) if o != target]
                for other, table in others:
                    take_out(other, table, pc.is_in(table["signature_id"], value_set=pa.array(ids, pa.string())))
        except (OSError, OutputError) as exc:
            raise Unpublished(self._unpublished(getattr(exc, "strerror", None) or str(exc))) from None
        finally:
            self.release()
        return self.new

    def _unpublished(self, why: str) -> str:
        """What a failed ``publish`` left: staged files (the next push lands them) or older copies in place."""
        staged, target = self.parts[0][0], self.parts[0][1]
        head = f"lake {staged.parents[3]}: the store took batch {target.stem} ({why}), but "
        left = [s for s, *_ in self.parts if s.exists()]
        if left:
            return (head + f"{len(left)} of its lake file(s) stay staged (first {left[0]}): the next push that "
                    f"reaches the store lands them")
        return (head + "earlier copies of its signatures stay in other files of their partitions (rows read "
                "twice where they differ); sending them again takes them out")

    def discard(self) -> None:
        """Remove the staged files: the store did not take the batch."""
        for staged, _, _, _ in self.parts:
            for path in (effects_of(staged), staged):
                path.unlink(missing_ok=True)
        self.release()

    def release(self) -> None:
        """Unlock the staged files, leaving them where they are."""
        for *_, fd in self.parts:
            if fd is not None:
                os.close(fd)
        self.parts = [(staged, target, ids, None) for staged, target, ids, _ in self.parts]


def stage_signatures(lake: Path, rows: Iterable[Mapping], name: str) -> Landing:
    """Write sent signature rows (``withhold``'s) into their partitions under staged names, to become ``name``.parquet
    (``Landing.publish``); each partition's files are read whole first (one unreadable: nothing staged, so the
    store does not take a batch the lake could not land). What was staged before an error is removed."""
    parts: dict[tuple[str, str], list[Mapping]] = defaultdict(list)
    for r in rows:
        parts[(str(r["created_date"]), r["tenant_id"])].append(r)
    landing = Landing()
    try:
        for (date, tenant), group in sorted(parts.items()):
            group = list({r["signature_id"]: r for r in group}.values())
            ids = [r["signature_id"] for r in group]
            target = lake_file(lake, tenant, "signatures", date, name)
            lake_file(lake, tenant, "effects", date, name)  # a link on the effects side is refused too
            there = set()
            for other in partition_files(target):  # the target too: a retry's
                there |= set(read_table(other).column("signature_id").to_pylist()) & set(ids)
            sig = pa.Table.from_pydict({f.name: [row_value(r, f.name) for r in group] for f in SIGNATURES},
                                       schema=SIGNATURES)
            eff = [(r["tenant_id"], r["signature_id"], k, float(v)) for r in group
                   for k, v in (r.get("effects") or {}).items()]
            staged = target.with_name(f"{name}.{secrets.token_hex(4)}{STAGED}")
            landing.parts.append((staged, target, ids, _write_locked(sig, staged)))
            write_file(pa.Table.from_pydict({c: [e[i] for e in eff] for i, c in enumerate(EFFECTS.names)},
                                            schema=EFFECTS), effects_of(staged))
            landing.new += len(set(ids) - there)
    except BaseException:
        landing.discard()
        raise
    return landing


def write_signatures(lake: Path, rows: Iterable[Mapping], name: str) -> int:
    """Write sent signature rows into their partitions as ``name``.parquet, then take them out of the partition's
    other files (the row last sent is the one kept): staged and published at once, with no store to wait for.
    Returns the signatures that were not in the lake before."""
    return stage_signatures(lake, rows, name).publish()


def reconcile(lake: Path, tenant: str, held: Callable[[list[str]], Mapping[str, Mapping]]) -> tuple[int, list[str]]:
    """Bring the staged files a push left in ``tenant``'s folder (the store lost mid-commit, the push killed, a
    rename failed) to what the store holds: of their signatures, the ones the store holds are landed as the store
    holds them (``held``: signature id -> the stored row with its ``effects``), the others dropped. A staged file
    another push holds locked is left to it. Returns (the signatures landed, one line per staged file left: no
    locks to tell a live push's from a dead one's, or unreadable)."""
    refuse_links(lake, tenant)
    published, left = 0, []
    for staged in staged_files(lake, tenant):
        fd = lock_left(staged)
        if fd == NO_LOCKS:
            left.append(f"lake file {staged}: the lake offers no file locks, so a live push's file cannot be told "
                        f"from one a dead push left; it stays staged (remove it, and its effects file, once no push "
                        f"runs)")
            continue
        if fd is None:
            continue
        try:
            try:
                ids = read_table(staged, ["signature_id"]).column("signature_id").to_pylist()
            except OutputError as exc:
                left.append(f"{exc}; it stays staged")
                continue
            stored = held(ids) if ids else {}
            kept = [stored[i] for i in dict.fromkeys(ids) if i in stored]
            if kept:
                published += len(kept)
                write_signatures(lake, kept, staged.name.removesuffix(STAGED).rsplit(".", 1)[0])
            for path in (effects_of(staged), staged):
                path.unlink(missing_ok=True)
        finally:
            os.close(fd)
    return published, left


def _write_locked(table: pa.Table, staged: Path) -> int | None:
    """Write ``table`` to the new file ``staged``: under a name no reconcile lists, locked before a byte is written,
    then renamed (the lock goes with it), so a reconcile never takes a live push's file. The open, locked
    descriptor (None where the filesystem offers no locks)."""
    make_folder(staged.parent, "lake folder")
    writing = staged.with_name(staged.name.removesuffix(STAGED) + WRITING)
    try:
        fd = os.open(writing, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    except OSError as exc:
        raise OutputError(f"lake file {staged}: cannot write ({exc.strerror or exc.__class__.__name__})") from None
    locked = True
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as exc:
            if exc.errno not in UNLOCKABLE:
                raise
            locked = False
        with os.fdopen(os.dup(fd), "wb") as f:
            pq.write_table(table, f, compression="zstd")
            f.flush()
            os.fsync(f.fileno())
        os.replace(writing, staged)
    except (OSError, pa.ArrowException) as exc:
        os.close(fd)
        writing.unlink(missing_ok=True)
        raise OutputError(f"lake file {staged}: cannot write ({getattr(exc, 'strerror', None) or exc})") from None
    if not locked:
        os.close(fd)
        return None
    return fd
