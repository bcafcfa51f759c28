"""The site's audit log: one JSON line per export (what, when, how many rows, which policy version).

Append-only at the site, never sent. A line is written whole (one ``write`` of an ``O_APPEND``
file, then fsync), so a crash leaves every earlier line intact. Statuses: ``queued`` (in the
outbox), ``sent``, ``duplicate`` (the store had every row), ``nothing`` (an empty export),
``held`` (the policy in force no longer lets a queued batch leave; ``reason`` says why),
``refused`` (the store refused it; ``reason``) and ``probed`` (a run's findings sent by ``fleet
similar`` to look for similar faults, never stored); a held or refused batch stays in the outbox. A
push's export (``queued`` or ``nothing``) is logged with ``retention_counted_on``, the UTC date its retention was
counted from (rows older by ``retention_days`` stayed at the site), which ``when_utc`` need not be. A
batch that leaves is logged with ``policy_in_force``, the version of the policy it left under.
``retention``: the push's retention deleted ``rows`` of the site's rows from ``destination`` (rows
older than ``before``), or, with ``reason``, did not run there; it names no batch. ``withdrawn``: ``fleet withdraw``
deleted ``rows`` (every one of the site's) from ``destination``; it names no batch.

The log is written and read only as a file of the site folder's own: a link there is refused, never followed (a
link to nothing, followed, put the site's log wherever it pointed, outside the site; read, another site's log was
shown as this one's), and so is a hard link, a second name elsewhere of the same file (every entry appended here
appeared there too). Each rule is checked on the file opened (``_open``), not on the path before it is opened: a
link swapped in between a check and the open was followed (another site's log shown as this one's).

A damaged log is read as far as it goes: ``scan_audit`` returns the entries and names each line
it cannot read; ``read_audit`` refuses a damaged log in one line.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

from cellguard.dates import utc_now
from cellguard.errors import ConfigError, OutputError
from cellguard.fleet.export import Batch
from cellguard.fleet.policy import DataPolicy
from cellguard.output import special_kind
from cellguard.yaml_file import read_opened

AUDIT_FILE = "audit.jsonl"
STATUSES = ("queued", "sent", "duplicate", "nothing", "held", "refused", "probed", "retention", "withdrawn")
FIELDS = {"when_utc": str, "what": str, "rows": int, "withheld_rows": int, "policy_version": str, "batch_id": str,
          "status": str}  # in every entry, of these types
MAX_AUDIT_BYTES = 1 << 30  # [bytes] about 3 million entries
APPEND = os.O_WRONLY | os.O_APPEND  # how the log is opened to be appended to (and checked before, creating nothing)
NO_LINKS = "the site's files are written only in its folder, never through a link: move what it names there, or " \
           "remove the link"


def _hard_linked(path: Path, names: int) -> str:
    """Why an audit log with ``names`` names is not appended to, and the copy that makes it the site's own."""
    return (f"audit log {path}: a hard link ({names} names of one file, as a backup by hard links makes), where every "
            f"entry appended here appears too: give the site a copy of its own (cp '{path}' '{path}.own' && mv "
            f"'{path}.own' '{path}'), then run the command again")


class AuditError(ConfigError):
    """A site folder or audit log that cannot be read."""


def append_audit(site_dir: Path, batch: Batch, status: str, destination: str, **more: str) -> dict:
    """Append the export of ``batch`` (``status``: one of ``STATUSES``) to the log; ``more``: fields such as
    ``reason`` and ``policy_in_force``."""
    return _append(site_dir, {"what": batch.export, "rows": batch.rows, "withheld_rows": batch.withheld_rows,
                              "policy_version": batch.policy_version, "batch_id": batch.batch_id,
                              "tenant_id": batch.tenant_id, "site_id": batch.site_id, "status": status,
                              "destination": destination, **more})


def append_retention(site_dir: Path, policy: DataPolicy, removed: int, destination: str, **more: str) -> dict:
    """Append what ``policy``'s retention deleted from ``destination`` (``more``: ``before``, or ``reason`` where
    it did not run): a deletion cannot be undone, so the site's log says what went, though no batch did."""
    return _append_deletion(site_dir, policy, "retention", removed, destination,
                            retention_days=policy.retention_days, **more)


def append_withdrawal(site_dir: Path, policy: DataPolicy, removed: int, destination: str,
                      store_tenant: str | None = None) -> dict:
    """Append that ``fleet withdraw`` deleted ``removed`` rows, all the site's, from ``destination``; from a store,
    ``store_tenant``: the tenant its credentials logged in as (only its own rows could be deleted)."""
    more = {"store_tenant": store_tenant} if store_tenant is not None else {}
    return _append_deletion(site_dir, policy, "withdrawn", removed, destination, **more)


def _append_deletion(site_dir: Path, policy: DataPolicy, status: str, removed: int, destination: str,
                     **more) -> dict:
    return _append(site_dir, {"what": policy.export, "rows": removed, "withheld_rows": 0,
                              "policy_version": policy.version, "batch_id": "", "tenant_id": policy.tenant,
                              "site_id": policy.site, "status": status, "destination": destination, **more})


def _append(site_dir: Path, fields: dict) -> dict:
    """Write ``fields``, stamped with the time, as one whole line at the end of the log."""
    entry = {"when_utc": utc_now().isoformat(timespec="seconds"), **fields}
    path = Path(site_dir) / AUDIT_FILE
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, st = _open(path, APPEND | os.O_CREAT)
        try:
            if not stat.S_ISREG(st.st_mode):
                raise OutputError(_not_regular(path, st.st_mode))
            if st.st_nlink > 1:  # of the file opened: a link made after the push's check is seen too
                raise OutputError(_hard_linked(path, st.st_nlink))
            os.write(fd, (json.dumps(entry, sort_keys=True) + "\n").encode())
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        raise _cannot_append(path, exc) from None
    return entry


def _cannot_append(path: Path, exc: OSError) -> OutputError:
    """Why the log at ``path`` could not be opened to append (``exc``), in one line."""
    if exc.errno == errno.ELOOP:
        return OutputError(f"audit log {path}: a link; {NO_LINKS}")
    if exc.errno in (errno.ENXIO, errno.EISDIR):  # a FIFO no one reads or a socket (opened to wait, a push hung
        return OutputError(_not_regular(path, _mode_of(path)))  # for good), a folder
    return OutputError(f"audit log {path}: cannot append ({exc.strerror or exc.__class__.__name__})")


def _open(path: Path, flags: int) -> tuple[int, os.stat_result]:
    """(``path`` opened with ``flags``, the opened file's status): never through a link (``O_NOFOLLOW``: ELOOP) and
    never waiting (``O_NONBLOCK``: a FIFO waits for its other end), so what the caller checks is the file it then
    reads or writes, whatever the path was made to name meanwhile."""
    fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o640)
    try:
        return fd, os.fstat(fd)
    except OSError:
        os.close(fd)
        raise


def _not_regular(path: Path, mode: int | None) -> str:
    """What the audit log at ``path`` (of ``mode``, None: not known) is instead of a regular file."""
    what = "a folder" if mode is not None and stat.S_ISDIR(mode) else special_kind(mode or 0)
    return f"{path}: is {what}, not a regular audit log file"


def _mode_of(path: Path) -> int | None:
    """``path``'s mode, to name what it is, or None if it cannot be looked at."""
    try:
        return os.lstat(path).st_mode
    except OSError:
        return None


def destination_of(entry: dict) -> str | None:
    """Where ``entry``'s rows went or were deleted from (a store's ``host:port/database``, never its password; a
    lake's path; ``nowhere``: no store given); None for an entry logged without one."""
    where = entry.get("destination")
    return where if isinstance(where, str) else None


def refuse_links(site_dir: Path, *names: str) -> None:
    """ConfigError naming the first of ``names`` (paths in ``site_dir``) that is a link, to anything or nothing."""
    for name in names:
        if (Path(site_dir) / name).is_symlink():
            raise _a_link(site_dir, name)


def _a_link(site_dir: Path, name: str) -> ConfigError:
    """The error naming ``name`` in ``site_dir`` as a link, and where it points (if it still does)."""
    try:
        to = f" to {os.readlink(Path(site_dir) / name)}"
    except OSError:  # swapped back since
        to = ""
    return ConfigError(f"--site-dir {site_dir}: {name} is a link{to}; {NO_LINKS}")


def check_log(site_dir: Path) -> None:
    """CellguardError naming the site's audit log, before a command that appends to it writes anything (a site key,
    a queued batch, a deletion), if the append would be refused: a link, symbolic or hard (a second name elsewhere
    of the same file, where every entry appended here appears too, and another site's appear here), something
    other than a regular file (a FIFO, a folder, a socket), a file it cannot append to, or none in a folder it
    cannot write. It is opened as the append opens it, creating nothing: refused only at the append, a push had
    made the site's key and queued its batch, a withdrawal deleted what the log then never said. Reading one is
    harmless (``scan_audit`` refuses only a symbolic link)."""
    path = Path(site_dir) / AUDIT_FILE
    try:
        fd, st = _open(path, APPEND)
    except FileNotFoundError:  # none yet: the append makes it, in a folder it may write (a withdrawal deleted first)
        if path.parent.is_dir() and not os.access(path.parent, os.W_OK | os.X_OK):
            raise OutputError(f"audit log {path}: cannot create it (its folder is not writable)") from None
        return
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _a_link(site_dir, AUDIT_FILE) from None
        raise _cannot_append(path, exc) from None
    os.close(fd)
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(_not_regular(path, st.st_mode))
    if st.st_nlink > 1:
        raise ConfigError(f"--site-dir {site_dir}: {_hard_linked(path, st.st_nlink)}")


def check_site_dir(site_dir: Path, missing_ok: bool = False) -> None:
    """AuditError unless ``site_dir`` is a folder (or, ``missing_ok``, nothing yet: a push makes it)."""
    site_dir = Path(site_dir)
    if missing_ok and not os.path.lexists(site_dir):  # looked at first: one made meanwhile is then seen a folder
        return
    if not site_dir.is_dir():
        raise AuditError(f"--site-dir {site_dir}: " + ("not a folder" if site_dir.exists() else "no such folder"))


def read_audit(site_dir: Path) -> list[dict]:
    """Every entry of the site's log; AuditError on a damaged log or a ``site_dir`` that is not a folder."""
    entries, damaged = scan_audit(site_dir)
    if damaged:
        raise AuditError(f"audit log {Path(site_dir) / AUDIT_FILE}: {damaged[0]}"
                         + (f" (and {len(damaged) - 1} more damaged line(s))" if len(damaged) > 1 else ""))
    return entries


def scan_audit(site_dir: Path) -> tuple[list[dict], list[str]]:
    """(the entries that can be read, one line per line that cannot). No log yet: no entries.
    AuditError when ``site_dir`` is not a folder or the log is not a file that can be read; ConfigError when it is
    a symbolic link: it is read as the writes would take it, never followed (a hard link, a backup's second name of
    the site's own file, reads as it is)."""
    check_site_dir(site_dir)
    data = _read(site_dir)
    entries, damaged = [], []
    for number, raw in enumerate(data.split(b"\n"), 1):
        if not raw.strip():
            continue
        try:
            entry = json.loads(raw)
        except (ValueError, RecursionError):  # not JSON, or not UTF-8: a torn or overwritten line
            damaged.append(f"line {number}: not a JSON entry")
            continue
        if not isinstance(entry, dict):
            damaged.append(f"line {number}: not an audit entry (a JSON {type(entry).__name__})")
            continue
        wrong = [k for k, kind in FIELDS.items()
                 if not isinstance(entry.get(k), kind) or isinstance(entry.get(k), bool)]
        if wrong:
            damaged.append(f"line {number}: not an audit entry ({', '.join(wrong)} missing or mistyped)")
            continue
        entries.append(entry)
    return entries, damaged


def _read(site_dir: Path) -> bytes:
    """The bytes of the site's log (none yet: empty), read from the file opened (``_open``): AuditError for one that
    is not a regular file, cannot be read or is larger than ``MAX_AUDIT_BYTES``, ConfigError for a symbolic link."""
    path = Path(site_dir) / AUDIT_FILE
    try:
        fd, st = _open(path, os.O_RDONLY)
    except FileNotFoundError:
        return b""
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _a_link(site_dir, AUDIT_FILE) from None
        if exc.errno == errno.ENXIO:  # a socket (it cannot be opened): named as the append names it
            raise AuditError(_not_regular(path, _mode_of(path))) from None
        raise AuditError(f"{path}: cannot read the audit log file ({exc.strerror or exc.__class__.__name__})") from None
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise AuditError(_not_regular(path, st.st_mode))
    return read_opened(fd, path, "audit log", AuditError, MAX_AUDIT_BYTES)
