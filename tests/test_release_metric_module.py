"""A gate metric is one module in ``cellguard.release.metrics``: dropped in, a plan's gate can use it.

Before, a metric's own file was not enough: it was unknown to every plan until the registry's list in
``release/metrics.py`` named it too."""

from __future__ import annotations

import os
import re
import sys
from contextlib import contextmanager

import pytest
from release_helpers import CELL, ONE, promoted_site, write_plan

from cellguard.plugins import PluginError
from cellguard.release import Store, load_plan, metrics, run_stage
from cellguard.release.errors import GateError

CYCLES_SEEN = '''
from cellguard.release.metrics import Measure, Metric, cycles_in


def cycles_seen(runs) -> Measure:
    n = cycles_in(runs)
    return Measure(float(n), n, tuple(f"{r.label()}: {len(r.cycles)} cycles" for r in runs))


METRICS = (Metric("cycles_seen", "", cycles_seen),)
'''
BUILT_IN = ["chunk_seam_jump_max_mrad", "cycle_time_p95_s", "drift_alarms", "inference_latency_p99_ms",
            "interventions_per_hour", "limit_violations", "place_error_p95_mm", "protective_stops",
            "shadow_distance_p95_mrad", "shadow_would_clamp", "shadow_would_stop", "success_rate"]


@contextmanager
def dropped_in(folder, name: str, text: str):
    """The package's modules and ``name`` (``text``, in ``folder``) as the metrics discovered; as before after."""
    (folder / f"{name}.py").write_text(text)
    kept = list(metrics.__path__)
    metrics.__path__.append(str(folder))
    try:
        yield metrics.discover()
    finally:
        metrics.__path__[:] = kept
        sys.modules.pop(f"{metrics.__name__}.{name}", None)
        metrics.discover()


def test_a_metric_module_dropped_into_the_package_is_a_plans_gate(tmp_path):
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [ONE, {**ONE, "name": "two"}],
                                                      "gates": [{"metric": "cycles_seen", "min": 2}]}})
    with pytest.raises(GateError) as refused:
        load_plan(plan)
    head, _, known = str(refused.value).partition("; known: ")
    assert head == f"{plan}: stages.sim.gates[0]: unknown metric 'cycles_seen'"
    assert sorted(known.split(", ")) == BUILT_IN
    (tmp_path / "extra").mkdir()
    with dropped_in(tmp_path / "extra", "cycles_seen", CYCLES_SEEN) as known:
        assert sorted(known) == sorted([*BUILT_IN, "cycles_seen"])
        site, (rid,) = promoted_site(tmp_path)
        result = run_stage(Store(site), load_plan(plan)["sim"], CELL, "sim")
    (gate,) = result.gates
    assert (gate.metric, gate.status, gate.value, gate.cycles) == ("cycles_seen", "pass", 2.0, 2)
    assert len(gate.evidence) == 2 and all(e.endswith(": 1 cycles") for e in gate.evidence)
    with pytest.raises(GateError, match="unknown metric 'cycles_seen'"):  # gone with its module
        load_plan(plan)


@pytest.mark.parametrize("text, file, why", [  # the file: the second, by name, of the modules taking one name
    ("from cellguard.release.metrics import Metric\nMETRICS = (Metric('success_rate', '', len),)\n", "cycles",
     r"metric 'success_rate' is defined twice: cellguard\.release\.metrics\.again \(.*again\.py\) and "
     r"cellguard\.release\.metrics\.cycles$"),
    ("METRICS = ['success_rate']\n", "again", r"a metric module defines METRICS, a tuple of Metric$"),
])
def test_a_module_that_takes_a_metrics_name_or_defines_none_is_refused_naming_it(tmp_path, text, file, why):
    """A second ``success_rate`` would have replaced the one every plan's gate means, unseen."""
    folder = {"cycles": metrics.__path__[0], "again": tmp_path}[file]
    with pytest.raises(PluginError, match=f"^{re.escape(os.path.join(folder, file + '.py'))}: {why}"), \
            dropped_in(tmp_path, "again", text):
        pass
    assert metrics.METRICS["success_rate"].compute.__module__ == "cellguard.release.metrics.cycles"
