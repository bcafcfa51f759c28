"""A sim-server address is ``udp://127.0.0.1:PORT`` and nothing else.

A path, query, fragment, user or whitespace in it was dropped without a word and the run drove the robot on the
port (``udp://127.0.0.1:5000/x?y=1`` ran on port 5000); a trailing space or ``tcp://`` was refused.
"""

from __future__ import annotations

import json

import pytest
from sim_server_util import server_counters, served
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ScenarioError
from cellguard.robot.bridges.sim_server import parse_address


@pytest.fixture(scope="module")
def served_port():
    with served() as port:
        yield port


@pytest.mark.parametrize("extra", ["/x?y=1", "/", "?", "#f", "?y=1", " "])
def test_an_address_with_text_after_the_port_is_one_line_exit_2_and_the_server_never_hears_it(served_port, extra,
                                                                                               tmp_path):
    address = f"udp://127.0.0.1:{served_port}{extra}"
    path = tmp_path / "s.yaml"
    path.write_text(f"cell: arm-pick-place\nrobot: {json.dumps('sim-server:' + address)}\n"
                    "cycle: {source: time, seconds: 1}\nacceptance_cycles: 1\nproduction_cycles: 0\n")
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert result.stderr == (f"error: robot: sim-server address must be udp://127.0.0.1:PORT (loopback, port "
                             f"1-65535, nothing else), got {address!r}\n")
    assert not (tmp_path / "out").exists()
    assert server_counters(served_port)["sessions"] == 0  # no run said hello to it


@pytest.mark.parametrize("address", ["udp://user@127.0.0.1:5000", " udp://127.0.0.1:5000", "udp://127.0.0.1:50\t00",
                                     "udp://127.0.0.1:5000/x?y=1", "127.0.0.1:5000#f"])
def test_an_address_with_anything_beside_scheme_host_and_port_is_refused(address):
    with pytest.raises(ScenarioError, match=r"^robot: sim-server address must be udp://127\.0\.0\.1:PORT"):
        parse_address(address)


@pytest.mark.parametrize("address", ["udp://127.0.0.1:5000", "127.0.0.1:5000", "udp://localhost:5000",
                                     "UDP://LOCALHOST:5000", "udp://127.0.0.1:05000"])
def test_the_address_forms_taken_before_are_still_taken(address):
    assert parse_address(address) == ("127.0.0.1", 5000)
