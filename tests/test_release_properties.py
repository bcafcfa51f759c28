"""Properties: any one edited or deleted log entry breaks the chain; too few cycles never pass."""

from __future__ import annotations

import json

from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.record.reader import CycleRecord
from cellguard.release import Store, verify_log
from cellguard.release import log as release_log
from cellguard.release.evidence import RunEvidence
from cellguard.release.gates import Gate, evaluate
from cellguard.release.reductions import LimitTicks, reduce_chunks

bodies = st.lists(st.dictionaries(st.sampled_from(["kind", "cell", "stage", "reason"]),  # no release: it has no bundle
                                  st.text(max_size=8), min_size=1), min_size=1, max_size=6)


@settings(max_examples=30, deadline=None)
@given(bodies=bodies, pick=st.integers(min_value=0), delete=st.booleans())
def test_any_single_edit_or_deletion_is_found(tmp_path_factory, bodies, pick, delete):
    store = Store(tmp_path_factory.mktemp("log"))
    for body in bodies:
        with store.transaction():
            release_log.append(store, body)
    assert verify_log(store) == []
    seq = pick % len(bodies) + 1
    if delete:
        store.db.execute("DELETE FROM log WHERE seq=?", (seq,))
    else:
        body = json.loads(store.db.execute("SELECT body FROM log WHERE seq=?", (seq,)).fetchone()[0])
        body["reason"] = body.get("reason", "") + "x"
        store.db.execute("UPDATE log SET body=? WHERE seq=?", (json.dumps(body), seq))
    assert verify_log(store)


def _run(successes: list[bool]) -> RunEvidence:
    cycles = tuple(CycleRecord(i, "acceptance", i * 5_000_000_000, i * 5_000_000_000 + 4_400_000_000, ok, {}, {}, {})
                   for i, ok in enumerate(successes))
    return RunEvidence("r", "synthetic", ".", {}, cycles, (), reduce_chunks(()), LimitTicks(), None)


@settings(max_examples=60, deadline=None)
@given(successes=st.lists(st.booleans(), max_size=12), min_cycles=st.integers(1, 15),
       threshold=st.floats(0.0, 1.0))
def test_a_gate_never_passes_on_fewer_cycles_than_min_cycles(successes, min_cycles, threshold):
    result = evaluate(Gate(metric="success_rate", min=threshold, min_cycles=min_cycles), [_run(successes)])
    if len(successes) < min_cycles:
        assert result.status != "pass"
    if result.status == "pass":
        assert result.value >= threshold and result.cycles >= min_cycles
