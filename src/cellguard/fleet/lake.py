"""The Parquet lake: signatures (and their effect sizes) partitioned by tenant and date.

``LAKE/tenant=T/signatures/date=YYYY-MM-DD/<name>.parquet`` and the same under ``effects/``.
One folder per tenant (created owner-only, 0700), so the lake is fenced the way the store is:
the operator grants each tenant its own folder (file system or object-store prefix rights) and
the engines read a tenant's own rows from that folder only (``rights.py``). A row is the
tenant's whose folder holds it: one that names another tenant is not read (a tenant could
otherwise invent customers, and a group under k would pass), and a link is never followed (it
could lead into another tenant's folder).

Each batch is one file per partition, named by the batch's content hash, landed as the store commits it
(``landing``: staged under ``NAME.TOKEN.staged`` until then, which no reader lists). Its signatures are then
taken out of the partition's other files, so each signature is in the lake once, as last sent: re-sending a
batch replaces its file with the same rows, a growing folder pushed again moves its signatures into its latest
file, and a signature sent again with fields the policy now withholds loses them. The engines read a row once even
where a lake written before this rule holds it twice (``read_groups``). ``forget`` takes a
site's rows out (its retention, its consent withdrawn), from the staged files no live push holds
too. DuckDB (``duckdb_engine``) and Spark (``spark_engine``) read the same files.
"""

from __future__ import annotations

import datetime as dt
import fcntl
import os
import re
from collections import defaultdict
from collections.abc import Iterable, Mapping
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.signature import ID_PATTERN
from cellguard.output import UNLOCKABLE, atomic_file

SIGNATURES = pa.schema([
    ("signature_id", pa.string()), ("tenant_id", pa.string()), ("site_id", pa.string()),
    ("created_date", pa.date32()), ("cause", pa.string()), ("confidence", pa.float64()),
    ("robot_model", pa.string()), ("cell_type", pa.string()), ("onset_cycle", pa.int64()),
    ("detection_delay_cycles", pa.int64()), ("policy_version", pa.string()), ("calibration_version", pa.string()),
    ("cellguard_version", pa.string()), ("recovery", pa.string()), ("recovery_outcome", pa.string()),
    ("schema_version", pa.int32()),
])
EFFECTS = pa.schema([("tenant_id", pa.string()), ("signature_id", pa.string()), ("feature", pa.string()),
                     ("effect", pa.float64())])
STAGED = ".staged"  # a batch's lake file not yet visible (``NAME.TOKEN.staged``): no reader lists it
NO_LOCKS = -1  # ``lock_left``: the filesystem offers no locks, so a live push's staged file looks like a dead one's


def effects_of(sig_file: Path) -> Path:
    """The effects file paired with the signatures file ``sig_file`` (same partition, same name)."""
    return sig_file.parents[2] / "effects" / sig_file.parent.name / sig_file.name


def forget(lake: Path, tenant: str, site: str, before: dt.date | None = None) -> int:
    """Take ``site``'s signatures made before ``before`` (its retention; all of them when None, its consent
    withdrawn) out of ``tenant``'s folder, staged files no live push holds included (a push killed after its
    commit left them). Returns the signatures taken out; OutputError, nothing taken out, where a link in the
    folder would hide files from it or a file cannot be read (every file is read before one is changed)."""
    refuse_links(lake, tenant)
    oldest = f"date={before.isoformat()}" if before else "date=9999"
    found = [Path(f) for f in paths(lake, "signatures", tenant) if Path(f).parent.name < oldest]
    locks = []
    try:
        for staged in staged_files(lake, tenant):
            fd = lock_left(staged) if staged.parent.name < oldest else None
            if fd is not None and fd != NO_LOCKS:
                locks.append(fd)
                found.append(staged)
        tables = [(f, read_table(f)) for f in found]
        return sum(len(take_out(f, table, pc.equal(table["site_id"], site))) for f, table in tables)
    finally:
        for fd in locks:
            os.close(fd)


def staged_files(lake: Path, tenant: str) -> list[Path]:
    """``tenant``'s signatures files a push staged and has not published or discarded (``landing``), in order."""
    return sorted(tenant_dir(lake, tenant).glob(f"signatures/date=*/*{STAGED}"))


def lock_left(staged: Path) -> int | None:
    """A descriptor holding ``staged``'s lock if no live push holds it (the push that wrote it was lost or
    killed); None if one does or it is gone; ``NO_LOCKS`` where no locks are offered."""
    try:
        fd = os.open(staged, os.O_RDWR | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.path.exists(staged):  # not published or discarded meanwhile
            return fd
    except OSError as exc:
        if exc.errno in UNLOCKABLE:
            os.close(fd)
            return NO_LOCKS
    os.close(fd)
    return None


def newest(lake: Path, tenant: str, site: str) -> dt.date | None:
    """The date of ``site``'s newest signature in ``tenant``'s folder, or None: with no store's clock to check a
    retention's date against, the lake's own data is what it is checked with."""
    for f in reversed(paths(lake, "signatures", tenant)):  # the newest date's partition first
        if site in read_table(Path(f), ["site_id"]).column("site_id").to_pylist():
            return dt.date.fromisoformat(Path(f).parent.name.removeprefix("date="))
    return None


def check_lake(lake: Path) -> Path:
    """``lake`` if signatures can land there (a folder, or a path whose nearest existing parent is one),
    else OutputError: checked before anything is sent."""
    lake = Path(lake)
    probe = lake
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"--lake {lake}: {'not a folder' if probe == lake else f'{probe} is not a folder'}")
    return lake


def write_tables(lake: Path, signatures: pa.Table, effects: pa.Table, name: str) -> None:
    """Bulk form for large fleets: arrow tables already in the lake's schemas, one date and tenant."""
    date = signatures.column("created_date")[0].as_py().isoformat()
    tenant = signatures.column("tenant_id")[0].as_py()
    write_file(signatures.cast(SIGNATURES), lake_file(lake, tenant, "signatures", date, name))
    write_file(effects.cast(EFFECTS), lake_file(lake, tenant, "effects", date, name))


def tenant_dir(lake: Path, tenant: str) -> Path:
    """The tenant's own folder; the id is checked, so no glob or path can stand in for it."""
    if not isinstance(tenant, str) or not re.fullmatch(ID_PATTERN, tenant):
        raise ConfigError(f"tenant: expected an opaque id matching {ID_PATTERN}, got {tenant!r}")
    return Path(lake) / f"tenant={tenant}"


def tenants(lake: Path) -> list[str]:
    """The tenants with signatures in the lake (from the folder names: no file is opened)."""
    return sorted({tenant_of(f) for f in paths(lake, "signatures")})


def tenant_of(path: str) -> str:
    """The tenant whose folder holds the lake file ``path`` (``tenant=T/<relation>/date=D/<file>``)."""
    return Path(path).parents[2].name.removeprefix("tenant=")


def paths(lake: Path, relation: str, tenant: str | None = None) -> list[str]:
    """``relation``'s files, listed (the lake's own path is taken literally, never as a pattern); a file
    that is a link or lies behind one below the lake is not listed."""
    root = tenant_dir(lake, tenant).name if tenant is not None else "tenant=*"
    return sorted(str(p) for p in Path(lake).glob(f"{root}/{relation}/date=*/*.parquet") if _plain(p))


def read_groups(found: Iterable[str], schema: pa.Schema) -> list[tuple[str, list[str], bool]]:
    """The files to read, as (tenant, files, with DISTINCT): an engine keeps only the rows of each group
    that name its tenant, the folder's. A row can be repeated only within its partition (its date and
    tenant are part of its id), in a folder holding more than one file: those are read with DISTINCT.
    Each file's columns are checked against ``schema``, the relation's, first (``check_schema``)."""
    found = list(found)
    check_schema(found, schema)
    by_folder: dict[str, list[str]] = defaultdict(list)
    for f in found:
        by_folder[os.path.dirname(f)].append(f)
    groups: dict[tuple[str, bool], list[str]] = defaultdict(list)
    for folder in by_folder.values():
        groups[(tenant_of(folder[0]), len(folder) > 1)].extend(folder)
    return [(tenant, listed, shared) for (tenant, shared), listed in sorted(groups.items())]


_AGREED: dict[str, tuple[tuple[int, ...], pa.Schema]] = {}
"""Lake files whose footer had a relation's columns, for this process: path -> (``_stat`` of it then, the schema).
A footer costs 0.1 ms to read (seconds on a lake of 100,000 files, on every query); a file replaced or rewritten
since has another ``_stat`` and is read again. About 0.5 kB a file: emptied when it reaches ``_AGREED_MAX``."""
_AGREED_MAX = 200_000


def _stat(path: str) -> tuple[int, ...]:
    """What changes when a file is replaced (its inode, ctime) or rewritten in place (size, mtime, ctime)."""
    st = os.stat(path)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def check_schema(found: Iterable[str], schema: pa.Schema) -> None:
    """ConfigError naming the first of the lake files ``found`` whose columns (names, order, types, read from its
    footer) are not ``schema``'s. The engines read a relation's files as one table: DuckDB by position (an extra
    column failed with no file named, a column of another type was read and its rows counted), Spark by the schema
    given (it refused the other type); checked here, both refuse the same file. A file whose footer cannot be read
    is left to the engine, which names it damaged. A file found to agree is not read again while unchanged
    (``_AGREED``)."""
    want = [(f.name, f.type) for f in schema]
    for path in found:
        try:
            seen = _stat(path)
            if _AGREED.get(path) == (seen, schema):
                continue
            have = [(f.name, f.type) for f in pq.read_schema(path)]
        except (OSError, pa.ArrowException):
            continue
        if have == want:
            if len(_AGREED) >= _AGREED_MAX:
                _AGREED.clear()
            _AGREED[path] = (seen, schema)
        else:
            raise ConfigError(f"lake file {path}: {_difference(have, want)}; every file of its relation must have "
                              f"the lake's columns ({', '.join(n for n, _ in want)}): move it out of the lake")


def _difference(have: list[tuple[str, pa.DataType]], want: list[tuple[str, pa.DataType]]) -> str:
    """The first way the columns ``have`` differ from ``want``, in words."""
    types = dict(want)
    extra = [n for n, _ in have if n not in types]
    if extra:
        return f"column {extra[0]} is not one of the lake's"
    missing = [n for n in types if n not in dict(have)]
    if missing:
        return f"it has no column {missing[0]}"
    wrong = [(n, t) for n, t in have if t != types[n]]
    if wrong:
        return f"column {wrong[0][0]} is {wrong[0][1]}, the lake's is {types[wrong[0][0]]}"
    return "its columns are in another order (or repeated)"


def has_data(lake: Path) -> bool:
    return bool(paths(lake, "signatures"))


def refuse_links(lake: Path, tenant: str) -> None:
    """OutputError naming the first link in ``tenant``'s folder (the folder itself included): links are never
    followed in a lake (one reached another tenant's files), so a file behind one could be neither read nor
    withdrawn, and nothing is written through one."""
    own = tenant_dir(lake, tenant)
    found = [own] if own.is_symlink() else []
    if own.is_dir() and not found:
        for root, dirs, names in os.walk(own):
            found += [Path(root) / n for n in sorted(dirs + names) if os.path.islink(os.path.join(root, n))]
    if found:
        raise OutputError(f"lake {found[0]}: is a link; cellguard never follows links in a lake (one could reach "
                          f"another tenant's files): make it a folder or file of its own")


def lake_file(lake: Path, tenant: str, relation: str, date: str, name: str) -> Path:
    """The path of ``name``.parquet in a partition, its tenant's folder made; OutputError naming a link on the way."""
    own = tenant_dir(lake, tenant)
    target = own / relation / f"date={date}" / f"{name}.parquet"
    if _linked(target):
        refuse_links(lake, tenant)  # raises, naming the link
    try:
        own.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"lake folder {own}: cannot create ({exc.strerror or exc.__class__.__name__})") from None
    return target


def _plain(p: Path) -> bool:
    """A regular file reached from its tenant's folder through no link (the tenant folder, the relation
    and date folders and the file itself are not links)."""
    return p.is_file() and not _linked(p)


def _linked(p: Path) -> bool:
    """Whether the lake file ``p`` (``tenant=T/<relation>/date=D/<file>``), or a folder of it below the lake, is a
    link."""
    return any(q.is_symlink() for q in (p, *list(p.parents)[:3]))


def partition_files(target: Path) -> list[Path]:
    """The files of ``target``'s partition folder, links left out."""
    return sorted(p for p in target.parent.glob("*.parquet") if _plain(p)) if target.parent.is_dir() else []


def take_out(sig_file: Path, table: pa.Table, which: pa.ChunkedArray) -> set[str]:
    """Remove the rows ``which`` picks (a boolean mask over ``table``, the file's) from a signatures file
    and their effects from its effects file (same partition, same name); a file left empty is deleted.
    Returns the signature ids taken out."""
    mask = pc.fill_null(which, False)  # a null (no site) is not picked
    gone = table.filter(mask).column("signature_id")
    if not len(gone):
        return set()
    effects_file = effects_of(sig_file)
    _keep(sig_file, table.filter(pc.invert(mask)))  # the signatures first: an effect left alone is never read
    if _plain(effects_file):
        effects = read_table(effects_file)
        _keep(effects_file, effects.filter(pc.invert(pc.is_in(effects["signature_id"], value_set=gone))))
    return set(gone.to_pylist())


def read_table(path: Path, columns: list[str] | None = None) -> pa.Table:
    """A lake file's rows (``columns`` of them), or OutputError naming the file."""
    try:
        return pq.read_table(path, columns=columns, partitioning=None)
    except (OSError, pa.ArrowException) as exc:
        raise OutputError(f"lake file {path}: cannot read it ({exc.__class__.__name__})") from None


def _keep(path: Path, table: pa.Table) -> None:
    """``table`` in place of the file at ``path``, or no file when it is empty."""
    if table.num_rows:
        write_file(table, path)
        return
    try:
        path.unlink()
    except OSError as exc:
        raise OutputError(f"lake file {path}: cannot remove ({exc.strerror or exc.__class__.__name__})") from None


def row_value(row: Mapping, name: str):
    """A sent row's ``name`` field as the lake stores it (a date, not its ISO text)."""
    v = row.get(name)
    return dt.date.fromisoformat(v) if name == "created_date" and isinstance(v, str) else v


def write_file(table: pa.Table, path: Path) -> None:
    """``table`` as the file ``path``, whole or not at all."""
    with atomic_file(path, "lake file") as f:
        pq.write_table(table, f, compression="zstd")
