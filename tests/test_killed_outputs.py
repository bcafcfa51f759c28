"""A command killed outright (SIGKILL, the OOM killer, a power switch) runs no clean-up: every killed write of an
output file left its hidden temporary file (``.NAME.PID.TOKEN.tmp``, as large as the output) beside it for good. The
next write of the same file takes out exactly what a killed one left, and nothing that a live one or anyone else put
there."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from run_copies import recorded, run  # noqa: F401 (fixtures)
from typer.testing import CliRunner

from cellguard import output
from cellguard.cli import app
from cellguard.output import write_output

runner = CliRunner()

# The command in a process of its own that SIGKILLs itself right after its first ``call`` (rename: Path.rename,
# link: os.link, fsync: os.fsync) whose target is named argv[2] ("*": any): where a kill lands on a slow disk.
KILLED = """
import os, pathlib, sys
call, name = sys.argv[1], sys.argv[2]
owner = pathlib.Path if call == "rename" else os
real = getattr(owner, call)
def killed(*args, **kwargs):
    result = real(*args, **kwargs)
    if name == "*" or os.path.basename(str(args[1])) == name:
        os.kill(os.getpid(), 9)
    return result
setattr(owner, call, killed)
from cellguard.cli import app
app(sys.argv[3:], prog_name="cellguard")
"""


def _killed(call: str, name: str, *args) -> None:
    """Run the command ``args``, killed right after its first ``call`` onto ``name``."""
    proc = subprocess.run([sys.executable, "-c", KILLED, call, name, *map(str, args)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr


def _names(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


def _temporaries(folder: Path) -> list[str]:
    return [name for name in os.listdir(folder) if name.endswith(".tmp")]


def test_the_temporary_file_of_a_killed_write_is_removed_by_the_next(run, tmp_path):
    out = tmp_path / "ex"
    _killed("fsync", "*", "record", "export", run, "-o", out / "t.csv")
    assert len(_temporaries(out)) == 1 and "t.csv" not in os.listdir(out)  # the whole table, under its hidden name
    result = runner.invoke(app, ["record", "export", str(run), "-o", str(out / "t.csv")])
    assert result.exit_code == 0, result.output
    assert _names(out) == ["t.csv"]


def test_the_temporary_file_of_a_live_write_is_kept(tmp_path):
    """A write still going on holds its temporary file's lock: another write of the same file leaves it be."""
    live = tmp_path / ".t.csv.4000001.tmp"
    live.write_bytes(b"being written")
    fd = os.open(live, os.O_WRONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        write_output(tmp_path / "t.csv", "rows", "-o")
    finally:
        os.close(fd)
    assert _names(tmp_path) == [live.name, "t.csv"] and live.read_bytes() == b"being written"


def test_a_live_write_outlasts_another_write_of_the_same_file(tmp_path):
    """The other process's temporary file is written, locked, under its name until renamed into place."""
    go = tmp_path / "go"
    held = ("import sys, time; from pathlib import Path; from cellguard.output import atomic_file\n"
            "with atomic_file(Path(sys.argv[1]), '-o') as f:\n"
            "    f.write(b'first'); Path(sys.argv[2]).touch()\n"
            "    while Path(sys.argv[2]).exists(): time.sleep(0.02)\n")
    proc = subprocess.Popen([sys.executable, "-c", held, str(tmp_path / "t.csv"), str(go)])
    try:
        while not go.exists():
            assert proc.poll() is None
            time.sleep(0.02)
        write_output(tmp_path / "t.csv", "second", "-o")
        assert len(_temporaries(tmp_path)) == 1  # the live one's, kept
    finally:
        go.unlink()
    assert proc.wait(timeout=60) == 0
    assert _names(tmp_path) == ["t.csv"] and (tmp_path / "t.csv").read_text() == "first"


def test_a_temporary_file_taken_before_it_was_locked_is_made_again(tmp_path, monkeypatch):
    """Another write may find the new file before its lock is taken and remove it as a killed one's: the data then
    went to a file no name reaches and the rename failed. The file is looked up again once locked."""
    flock, taken = output.fcntl.flock, []

    def another_write_first(fd, operation):
        if not taken:
            taken.extend(_temporaries(tmp_path))
            os.unlink(tmp_path / taken[0])
        return flock(fd, operation)

    monkeypatch.setattr(output.fcntl, "flock", another_write_first)
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert taken and _names(tmp_path) == ["t.csv"] and (tmp_path / "t.csv").read_text() == "rows"


def test_without_locks_a_temporary_file_is_kept(tmp_path, monkeypatch):
    """Where the filesystem offers no flock, a temporary file is never known stale: it is left as it is."""
    stale = tmp_path / ".t.csv.4000001.tmp"
    stale.write_bytes(b"killed")

    def no_locks(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(output.fcntl, "flock", no_locks)
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert _names(tmp_path) == [stale.name, "t.csv"] and (tmp_path / "t.csv").read_text() == "rows"


@pytest.mark.parametrize("name", [".t.csv.4000001.tmp/", ".t.csv.x1.tmp", ".u.csv.4000001.tmp", "t.csv.1.tmp"])
def test_only_a_regular_temporary_file_of_the_same_output_is_removed(tmp_path, name):
    """A folder of that name, or the temporary file of another output (or not one at all), is kept."""
    kept = tmp_path / name.rstrip("/")
    kept.mkdir() if name.endswith("/") else kept.write_bytes(b"other")
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert _names(tmp_path) == sorted([kept.name, "t.csv"])


def _first_token(monkeypatch, token: bytes) -> None:
    """The first temporary name drawn has ``token``; the next ones are random again."""
    urandom, drawn = os.urandom, []

    def first(n: int) -> bytes:
        drawn.append(n)
        return token if len(drawn) == 1 else urandom(n)

    monkeypatch.setattr(os, "urandom", first)


def test_a_link_at_a_temporary_name_is_never_followed_and_another_name_is_drawn(tmp_path, monkeypatch):
    """A dangling link under the write's own temporary name: the write followed it (making its target) and spun at
    full CPU for ever, its check that the file it locked is the one under that name failing every time."""
    links = [tmp_path / f".t.csv.{os.getpid()}.tmp", tmp_path / f".t.csv.{os.getpid()}.00000000.tmp"]
    for link in links:  # the name before the token, and the first one drawn
        link.symlink_to(tmp_path / "elsewhere")
    _first_token(monkeypatch, bytes(4))
    write_output(tmp_path / "t.csv", "a,b\n", "--out")
    assert (tmp_path / "t.csv").read_text() == "a,b\n" and not (tmp_path / "elsewhere").exists()
    assert all(link.is_symlink() for link in links)  # not the write's own files: left as they are


# a write of argv[1] with a FIFO at its temporary name: the one before the token, and the first one drawn
FIFO = """
import os, sys
from pathlib import Path
from cellguard.output import write_output
drawn = []
def first_zero(n, urandom=os.urandom):
    drawn.append(n)
    return bytes(n) if len(drawn) == 1 else urandom(n)
os.urandom = first_zero
target = Path(sys.argv[1])
for name in (f".{target.name}.{os.getpid()}.tmp", f".{target.name}.{os.getpid()}.00000000.tmp"):
    os.mkfifo(target.with_name(name))
write_output(target, "rows", "-o")
"""


def test_a_fifo_at_a_temporary_name_never_hangs_the_write(tmp_path):
    """The temporary file was opened for writing whatever was there: a FIFO under its name (no reader) hung it."""
    proc = subprocess.run([sys.executable, "-c", FIFO, str(tmp_path / "t.csv")], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "t.csv").read_text() == "rows" and len(_temporaries(tmp_path)) == 2  # the FIFOs, kept


@pytest.mark.parametrize("name", [".t.csv.4000001.tmp", ".t.csv.4000001.0123abcd.tmp"],
                         ids=["before the token", "with it"])
def test_a_killed_writes_file_under_any_pid_is_removed(tmp_path, name):
    """Temporary names of 32 fixed slots left the ``.NAME.PID.tmp`` of writes killed before them for good."""
    (tmp_path / name).write_bytes(b"killed")
    write_output(tmp_path / "t.csv", "rows", "-o")
    assert _names(tmp_path) == ["t.csv"]


def test_a_killed_writes_file_from_before_the_token_is_removed_where_its_name_is_now_hashed(tmp_path):
    """A 240-byte name: ``.NAME.PID.tmp`` fits 255 bytes, ``.NAME.PID.TOKEN.tmp`` does not (hashed)."""
    target = tmp_path / ("a" * 236 + ".csv")
    (tmp_path / f".{target.name}.4000001.tmp").write_bytes(b"killed")
    write_output(target, "rows", "-o")
    assert _names(tmp_path) == [target.name]


@pytest.mark.parametrize("locks", ["none", "blind"])
def test_two_writes_of_one_pid_never_publish_a_mix(tmp_path, monkeypatch, locks):
    """Two writers of one pid (the first process of two containers) where flock is absent (none) or sees no other
    process's lock (blind) shared ``.NAME.PID.tmp``: B emptied A's file and wrote over it, and A published B's data
    then its own (none), or B's half (blind). Here both are in one process, A ending while B is half written."""
    def no_locks(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(output.fcntl, "flock", no_locks if locks == "none" else lambda fd, operation: None)
    target = tmp_path / "t.json"
    writes = [output.atomic_file(target, "-o"), output.atomic_file(target, "-o")]
    a = writes[0].__enter__()
    a.write(b"A" * 1000)
    a.flush()
    b = writes[1].__enter__()  # blind: takes A's file for a killed one's and removes it
    b.write(b"B" * 1000)
    b.flush()
    a.write(b"A" * 1000)
    with pytest.raises(output.OutputError) if locks == "blind" else contextlib.nullcontext():
        writes[0].__exit__(None, None, None)
    assert target.read_bytes() == b"A" * 2000 if locks == "none" else not target.exists()
    b.write(b"B" * 1000)
    writes[1].__exit__(None, None, None)
    assert target.read_bytes() == b"B" * 2000 and _names(tmp_path) == ["t.json"]


def test_a_write_stopped_right_after_its_rename_removes_no_other_file(tmp_path, monkeypatch):
    """SIGTERM right after the rename (the CLI's handler raises SystemExit there): the clean-up removed whatever then
    had the temporary name, free since the rename: another write's file. It removes only its own."""
    replace, taken = os.replace, []

    def renamed_then_stopped(source, destination):
        replace(source, destination)
        taken.append(Path(source))
        taken[0].write_bytes(b"another write's")  # the free name taken meanwhile
        raise SystemExit(143)

    monkeypatch.setattr(os, "replace", renamed_then_stopped)
    with pytest.raises(SystemExit):
        write_output(tmp_path / "t.json", "mine", "-o")
    monkeypatch.undo()
    assert (tmp_path / "t.json").read_text() == "mine" and taken[0].read_bytes() == b"another write's"


# a write of argv[1] by argv[3] that pauses half written (touching argv[4], until argv[5] exists); "noop": its flock
# sees no other process's lock (two NFS clients of one share mounted local_lock=flock)
HALF = """
import fcntl, os, sys, time
from pathlib import Path
if sys.argv[2] == "noop":
    fcntl.flock = lambda fd, operation: None
from cellguard.errors import OutputError
from cellguard.output import atomic_file
try:
    with atomic_file(Path(sys.argv[1]), "-o") as f:
        f.write(sys.argv[3].encode() * 1000)
        f.flush()
        Path(sys.argv[4]).touch()
        while not Path(sys.argv[5]).exists():
            time.sleep(0.01)
        f.write(sys.argv[3].encode() * 1000)
except OutputError as exc:
    print(exc)
"""


def test_a_write_whose_locks_see_nothing_never_publishes_another_writes_half(tmp_path):
    """Writer B, whose flock sees no lock, took live writer A's temporary file for a killed one's, removed it and made
    its own under the same fixed name (.t.json.0.tmp): A's rename then published B's half-written file."""
    target = tmp_path / "out" / "t.json"

    def start(who: str, locks: str) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-c", HALF, str(target), locks, who, str(tmp_path / f"{who}_half"),
                                 str(tmp_path / f"{who}_go")], stdout=subprocess.PIPE, text=True)
        while not (tmp_path / f"{who}_half").exists():
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        return proc

    a = start("A", "real")
    b = start("B", "noop")
    (tmp_path / "A_go").touch()
    a.communicate(timeout=60)
    assert not target.exists() or target.read_text() == "A" * 2000
    (tmp_path / "B_go").touch()
    b.communicate(timeout=60)
    assert target.read_text() == "B" * 2000 and _names(target.parent) == ["t.json"]


def test_many_writes_of_one_file_at_once_all_succeed(tmp_path):
    """Each write looked twice at whether its target was an open file no name reaches (a link to /proc/self/fd/N):
    another write's rename in between made a plain file name read as one, and 14 of 2,400 writes by 8 processes
    failed. A plain name is never such a link."""
    writes = ("import sys; from pathlib import Path; from cellguard.output import write_output\n"
              "for i in range(200): write_output(Path(sys.argv[1]), sys.argv[2] * 100, '-o')\n")
    procs = [subprocess.Popen([sys.executable, "-c", writes, str(tmp_path / "t.json"), who],
                              stderr=subprocess.PIPE, text=True) for who in "abcdef"]
    errors = [proc.communicate(timeout=300)[1] for proc in procs]
    assert [proc.returncode for proc in procs] == [0] * 6, errors
    assert _names(tmp_path) == ["t.json"] and (tmp_path / "t.json").read_text() in [c * 100 for c in "abcdef"]
