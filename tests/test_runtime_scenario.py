"""The scenario's runtime keys (robot, cycle, realtime) are validated like the rest: one line naming the key."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cellguard.errors import CellguardError, ScenarioError
from cellguard.robot.bridges import make_bridge, parse_bridge
from cellguard.robot.bridges.sim_server import parse_address
from cellguard.scenario import parse_scenario

BASE = {"cell": "arm-pick-place"}


@pytest.mark.parametrize("extra, key", [
    ({"realtime": {"inference": "gpu"}}, "realtime.inference"),
    ({"realtime": {"overrun_budget": -1}}, "realtime.overrun_budget"),
    ({"realtime": {"stale_s": 0}}, "realtime.stale_s"),
    ({"realtime": {"stop_category": 3}}, "realtime.stop_category"),
    ({"realtime": {"sleep": True}}, "realtime.sleep"),
    ({"cycle": {"source": "bell"}}, "cycle.source"),
    ({"cycle": {"seconds": 0}}, "cycle.seconds"),
    ({"robot": ""}, "robot"),
])
def test_bad_runtime_keys_are_refused_naming_the_key(extra, key):
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        parse_scenario({**BASE, **extra})


def test_defaults_keep_a_plain_scenario_on_its_simulated_cell():
    sc = parse_scenario(BASE)
    assert sc.robot == "sim" and sc.cycle.source == "task" and sc.realtime.inference == "thread"


def test_an_unknown_bridge_scheme_lists_the_known_ones():
    with pytest.raises(CellguardError, match="unknown robot bridge 'ur-rtde'; known: .*sim-server"):
        make_bridge("ur-rtde:192.168.0.2", parse_scenario(BASE))
    with pytest.raises(ScenarioError, match="SCHEME:ARGUMENT"):
        parse_bridge("sim-server")


@given(st.text(max_size=40))
def test_any_sim_server_address_parses_to_loopback_or_is_refused_naming_the_key(text):
    try:
        host, port = parse_address(text)
    except ScenarioError as exc:
        assert str(exc).startswith("robot: sim-server address")
    else:
        assert host == "127.0.0.1" and 1 <= port <= 65535
