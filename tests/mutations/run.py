"""Mutation check of the guard: every curated mutation (``mutations.py``) must make a guard test fail.

Each mutation is applied to a temporary copy of ``src/`` and ``tests/`` (the working tree is never
edited), and its tests run there with ``-x``; the copy shadows the installed package through
``PYTHONPATH``. Hypothesis runs with a fixed seed and without shrinking (a failure is enough).
Prints one JSON line per mutation and a summary; exits 1 if any mutation survives (listing them),
2 if a mutation no longer applies or its tests could not run.

    python tests/mutations/run.py [--jobs 2] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from mutations import MUTATIONS, Mutation  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PROFILE = ('\nfrom hypothesis import Phase, settings as _settings\n'
           '_settings.register_profile("mutations", phases=[Phase.explicit, Phase.reuse, Phase.generate], '
           'database=None, print_blob=False)\n')
IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", ".hypothesis", "*.egg-info")


def _copy(dest: Path) -> None:
    for part in ("src", "tests", "scenarios"):
        if (ROOT / part).exists():
            shutil.copytree(ROOT / part, dest / part, ignore=IGNORE)
    shutil.copy(ROOT / "pyproject.toml", dest / "pyproject.toml")
    with open(dest / "tests" / "conftest.py", "a") as f:
        f.write(PROFILE)


def _apply(m: Mutation, dest: Path) -> None:
    for rel, old, new in ((m.path, m.old, m.new), *m.also):
        path = dest / rel
        text = path.read_text()
        if text.count(old) != 1:
            raise LookupError(f"{m.name}: the text to mutate occurs {text.count(old)} times in {rel}, not once")
        path.write_text(text.replace(old, new))


def run_one(m: Mutation) -> dict:
    began = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=f"mutation-{m.name}-") as tmp:
        dest = Path(tmp)
        _copy(dest)
        try:
            _apply(m, dest)
        except LookupError as exc:
            return {"name": m.name, "check": m.check, "result": "stale", "why": str(exc)}
        env = {**os.environ, "PYTHONPATH": str(dest / "src"), "PYTHONDONTWRITEBYTECODE": "1"}
        cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "--hypothesis-seed=0",
               "--hypothesis-profile=mutations", *m.tests]
        proc = subprocess.run(cmd, cwd=dest, env=env, capture_output=True, text=True)
    # pytest: 1 = a test failed (killed), 0 = all passed (survived), anything else = could not run
    result = {0: "survived", 1: "killed"}.get(proc.returncode, "error")
    out = {"name": m.name, "check": m.check, "result": result, "seconds": round(time.monotonic() - began, 1)}
    if result == "error":
        out["why"] = (proc.stdout + proc.stderr)[-2000:]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2, help="mutations run at once")
    parser.add_argument("--only", nargs="*", default=None, help="run only these mutations")
    args = parser.parse_args(argv)
    chosen = [m for m in MUTATIONS if args.only is None or m.name in args.only]
    began = time.monotonic()
    results = []
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        for r in pool.map(run_one, chosen):
            print(json.dumps(r), flush=True)
            results.append(r)
    survivors = [r["name"] for r in results if r["result"] == "survived"]
    broken = [r["name"] for r in results if r["result"] in ("stale", "error")]
    print(json.dumps({"mutations": len(results), "killed": sum(r["result"] == "killed" for r in results),
                      "survived": survivors, "broken": broken, "seconds": round(time.monotonic() - began, 1)}))
    return 2 if broken else 1 if survivors else 0


if __name__ == "__main__":
    sys.exit(main())
