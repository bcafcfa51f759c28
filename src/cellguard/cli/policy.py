"""`cellguard train-demo-policy`: a small learned policy for the demos and tests."""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import BinaryIO

import typer

from cellguard.cli import stdout
from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.cli.text import say
from cellguard.errors import CellguardError, ConfigError, OutputError

SEED_MAX = 2**32 - 1  # the seed seeds numpy; the range of sim-server's --seed
# how an ONNX model cellguard saves begins (``policy.onnx_export``): field 1 (ir_version, one byte), then field 2
# (producer_name) "cellguard"; --overwrite replaces only such a model
ONNX_PRODUCER = b"\x12\x09cellguard"


def _cellguard_onnx(f: BinaryIO) -> bool:
    """Whether ``f`` begins as an ONNX model cellguard saved."""
    head = f.read(2 + len(ONNX_PRODUCER))
    return head[:1] == b"\x08" and head[2:] == ONNX_PRODUCER


@app.command("train-demo-policy")
def train_demo_policy(
    out: Path = typer.Option(Path("demo-policy.onnx"), "--out", "-o", help="ONNX file to write (a new file, "
                             "unless --overwrite)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing ONNX model at --out that "
                                   "cellguard wrote (or an empty file); any other file is kept."),
    cycles: int = typer.Option(10, min=2, max=500, help="Scripted demonstration cycles to record."),
    random_features: int = typer.Option(64, min=0, max=4096, help="Random tanh units beside the time basis."),
    seed: int = typer.Option(0, min=0, help="Seed of the demonstrations and the initial weights (0 to 2^32-1)."),
    fixture_dx_mm: float = typer.Option(0.0, "--fixture-dx-mm", min=-5.0, max=5.0,
                                        help="Record the demonstrations with the fixture moved this far in x \\[mm]."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON document on stdout."),
) -> None:
    """Clone the scripted arm program into a small MLP on the CPU; run it with `policy: onnx:FILE`."""
    from dataclasses import asdict

    from cellguard.record.outputs import OwnKind, refuse_output
    from cellguard.train.demo_policy import train_demo_policy as train

    try:
        # before the demonstrations are recorded: never over a record, into a run folder, or over a model
        # (one a release may have hashed) unless --overwrite, and then only over a model cellguard saved
        if seed > SEED_MAX:
            raise ConfigError(f"--seed: must be in 0..{SEED_MAX}, got {seed}")
        refuse_output(out, None, replace=overwrite, kind=OwnKind("an ONNX model", _cellguard_onnx))
        _refuse_unwritable(out)
        report = train(out, cycles=cycles, random_features=random_features, seed=seed, fixture_dx_mm=fixture_dx_mm,
                       overwrite=overwrite)
        stdout.written(f"the policy {report.path}")
    except CellguardError as exc:
        fail(exc)
    if as_json:
        sys.stdout.write(json.dumps(asdict(report)) + "\n")
        return
    say(f"trained on {report.samples} samples from {report.cycles} cycles in {report.seconds:.0f} s "
        f"({report.hidden} hidden units, joint error rms {report.rms_error_mrad:.2f} mrad, "
        f"worst {report.max_error_mrad:.2f} mrad); "
        f"written to {report.path}; run it with policy: onnx:{report.path}", err=False)


def _refuse_unwritable(out: Path) -> None:
    """OutputError unless a file can be made in the folder that will hold ``out`` (or the nearest one there is): a
    read-only folder failed only at the save, after minutes of training."""
    target = Path(os.path.realpath(out))
    folder = next(d for d in target.parents if d.is_dir())
    try:
        with tempfile.TemporaryFile(dir=folder):  # anonymous, or removed at once: nothing is left there
            pass
    except OSError as exc:
        raise OutputError(f"-o {out}: cannot write in {folder} ({exc.strerror or type(exc).__name__}); "
                          f"choose another path (nothing trained or written)") from None
