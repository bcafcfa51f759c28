"""The real cellguard runs a simulated fleet is built from (cached; used by benchmarks/fleet.py).

Short arm-cell scenarios, 6 acceptance and 6 production cycles, one fault each, several kinds
and magnitudes. ``python benchmarks/fleet_runs.py [DIR]`` makes the missing ones, two at a time.
"""

from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ACCEPTANCE, PRODUCTION, AT = 6, 6, 7
DEFAULT_DIR = Path("out/fleet-runs")


def _fault(kind: str, size: float) -> dict:
    return {
        "fixture_shift": {"kind": "fixture_shift", "at_cycle": AT, "dx_mm": size, "dy_mm": size / 3},
        "camera_shift": {"kind": "camera_shift", "at_cycle": AT, "dx_mm": size},
        "friction": {"kind": "friction_growth", "joint": "elbow", "from_cycle": AT, "per_cycle": size},
        "servo": {"kind": "servo_gain", "joint": "shoulder_lift", "factor": size, "at_cycle": AT},
        "tool_slip": {"kind": "tool_slip", "at_cycle": AT},
        "policy_latency": {"kind": "policy_latency", "at_cycle": AT, "ms": size},
        "policy_output": {"kind": "policy_nan", "at_cycle": AT},
    }[kind]


# (cause the injected fault should read as, magnitude); the pool builds the fleet, the held-out
# runs (other seeds and magnitudes) are the faults `fleet similar` is asked about
POOL = [("fixture_shift", 4.0), ("fixture_shift", 6.0), ("camera_shift", 3.0), ("camera_shift", 5.0),
        ("friction", 0.15), ("friction", 0.3), ("servo", 0.6), ("servo", 0.75), ("tool_slip", 0.0),
        ("policy_latency", 200.0), ("policy_latency", 350.0), ("policy_output", 0.0)]
HELD_OUT = [("fixture_shift", 5.0), ("camera_shift", 4.0), ("friction", 0.22), ("servo", 0.68),
            ("policy_latency", 280.0)]


def runs() -> list[tuple[str, str, dict]]:
    """(folder name, cause, scenario) of every run, pool first."""
    out = []
    for group, items, seed0 in (("pool", POOL, 100), ("held", HELD_OUT, 500)):
        for i, (cause, size) in enumerate(items):
            scenario = {"cell": "arm-pick-place", "seed": seed0 + i, "acceptance_cycles": ACCEPTANCE,
                        "production_cycles": PRODUCTION, "faults": [_fault(cause, size)]}
            out.append((f"{group}-{i:02d}-{cause}", cause, scenario))
    return out


def _make(folder: Path, scenario: dict) -> str:
    from cellguard.runtime import run_scenario
    from cellguard.scenario import parse_scenario

    tmp = folder.with_name(folder.name + ".partial")
    run_scenario(parse_scenario(scenario), tmp)
    tmp.rename(folder)
    return folder.name


def make_runs(root: Path = DEFAULT_DIR, workers: int = 2) -> dict[str, tuple[Path, str]]:
    """Every run folder by name (made if missing) with the cause it should read as."""
    root.mkdir(parents=True, exist_ok=True)
    todo = [(root / name, sc) for name, _, sc in runs() if not (root / name / "summary.json").is_file()]
    if todo:
        with ProcessPoolExecutor(workers) as pool:
            list(pool.map(_make, *zip(*todo)))
    return {name: (root / name, cause) for name, cause, _ in runs()}


if __name__ == "__main__":
    print(len(make_runs(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_DIR)))
