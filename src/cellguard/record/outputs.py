"""Where a command may write its output: never over a record, nor into a run folder.

Every command that writes an output (export, to-lerobot, recover, report) asks here first, before
it reads anything, so a mistyped ``-o`` cannot cost a record.
"""

from __future__ import annotations

from pathlib import Path

from cellguard.errors import RecordError
from cellguard.record.reader import record_file
from cellguard.record.scan import MAGIC
from cellguard.record.writer import RECORD_FILE


def refuse_output(output: Path, source: Path, to_folder: bool = False) -> None:
    """RecordError unless ``output`` may be written: nothing recorded is ever overwritten.

    Every command that writes (export, to-lerobot, recover, report) calls this before it reads
    anything. Refused, after following links: the record being read (``source``, a run folder or
    an .mcap file, whatever its bytes hold), a file that starts with the MCAP magic, and a run
    folder (one holding record.mcap) or anything in it, since its summary, index and baseline
    belong to the record. ``to_folder``: the output is a folder to fill, else a file.
    """
    try:
        target = Path(output).resolve()
        if target == record_file(source).resolve():
            raise RecordError(f"-o {output}: is the record being read; cellguard never overwrites a record; "
                              f"choose another path")
        run = next((d for d in (target, *target.parents) if (d / RECORD_FILE).exists()), None)
        if run is not None:
            where = "is a run folder" if run == target else f"is in the run folder {run}"
            raise RecordError(f"-o {output}: {where}, which holds a record; cellguard never overwrites a record "
                              f"or its run folder; choose a path outside it")
        if target.is_file():
            with open(target, "rb") as f:
                if f.read(len(MAGIC)) == MAGIC:
                    raise RecordError(f"-o {output}: is a record; cellguard never overwrites a record; "
                                      f"choose another path")
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop
        raise RecordError(f"-o {output}: cannot be checked ({getattr(exc, 'strerror', None) or exc})") from None
    if to_folder and target.exists() and not target.is_dir():
        raise RecordError(f"-o {output}: is a file; give a new folder")
    if not to_folder and target.is_dir():
        raise RecordError(f"-o {output}: is a folder; name a file to write")
