"""Small scenario files for the hostile cases, and the check that a refused run left nothing behind."""

from __future__ import annotations

from pathlib import Path

import yaml

from .expect import refused, snapshot

BASE = {"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 0, "production_cycles": 1}


def scenario_file(folder: Path, text: str | None = None, **fields) -> Path:
    """A scenario file in ``folder``: ``text`` as written, else BASE updated with ``fields``."""
    path = Path(folder) / f"scenario-{len(list(Path(folder).glob('scenario-*')))}.yaml"
    path.write_text(text if text is not None else yaml.safe_dump({**BASE, **fields}))
    return path


def run_refused(tmp_path: Path, scenario: Path, contains: str = "") -> str:
    """``cellguard run`` on ``scenario`` is one error line, exit 2, creates no --out folder, changes no file."""
    out = tmp_path / "refused-run"
    before = snapshot(tmp_path)
    line = refused(["run", scenario, "--out", out], contains=contains)
    assert not out.exists(), "a refused run left its --out folder behind"
    assert snapshot(tmp_path) == before
    return line
