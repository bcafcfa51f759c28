"""``cellguard sim-server --rate-hz``: a period is whole physics steps (1 ms for every cell), so a rate they cannot
serve within 1 % is refused naming the nearest served ones, and the start line says the rate served.

400 Hz was served at 500 Hz, 700 Hz at 1000 Hz and 60 Hz at 58.8 Hz without a word.
"""

from __future__ import annotations

import pytest
from cli_util import one_error
from sim_server_util import free_port
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import ConfigError


def _sim_server(rate: str):
    """``cellguard sim-server`` at ``rate`` for 50 ms on a free port."""
    args = ["sim-server", "arm-pick-place", "--port", str(free_port()), "--rate-hz", rate, "--duration-s", "0.05"]
    return CliRunner().invoke(app, args)


@pytest.mark.parametrize("rate, nearest", [("400", "333.3 and 500"), ("666", "500 and 1000"),
                                           ("700", "500 and 1000"), ("60", "58.82 and 62.5")])
def test_a_rate_not_served_within_1_percent_is_one_line_naming_the_nearest_and_exit_2(rate, nearest):
    assert one_error(_sim_server(rate)) == (
        f"error: --rate-hz: {rate} Hz is not served: a servo period is a whole number of the cell's 1 ms physics "
        f"steps; nearest rates served: {nearest} Hz")


@pytest.mark.parametrize("rate, served", [("333", "333.3 Hz (3 ms period)"), ("62.5", "62.5 Hz (16 ms period)"),
                                          ("1000", "1000 Hz (1 ms period)")])
def test_the_start_line_says_the_rate_served(rate, served):
    result = _sim_server(rate)
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[0].endswith(f" at {served}")


def test_the_client_is_told_the_served_period_and_a_rate_not_served_is_refused():
    from cellguard.runtime.sim_server import SimServer

    server = SimServer("arm-pick-place", 0, rate_hz=333)
    server.sock.close()
    assert (server.substeps, server.meta["dt_ns"]) == (3, 3_000_000)  # the bridge's period is the hello's dt_ns
    with pytest.raises(ConfigError, match="nearest rates served: 333.3 and 500 Hz"):
        SimServer("arm-pick-place", 0, rate_hz=400)


def test_a_cell_whose_physics_step_is_under_1_ms_is_refused_unless_served_at_a_rate(monkeypatch):
    """Served at its 0.5 ms step by default, every client refused its period after the server had started."""
    from cellguard.robot import registry
    from cellguard.robot.arm_cell import ArmPickPlace
    from cellguard.runtime.sim_server import SimServer

    class Fine(ArmPickPlace):
        name = "arm-fine"

        def __init__(self, seed=0):
            super().__init__(seed=seed)
            self.model.opt.timestep, self.dt_ns = 0.0005, 500_000

    monkeypatch.setitem(registry.CELLS, "arm-fine", Fine)
    with pytest.raises(ConfigError, match=r"^arm-fine: a servo period of 0\.5 ms is not one a run drives \(1 ms to "
                                          r"1 s\): serve it with --rate-hz, 50 to 1000 Hz$"):
        SimServer("arm-fine", free_port())
    server = SimServer("arm-fine", free_port(), rate_hz=500)
    try:
        assert server.dt_ns == 2_000_000
    finally:
        server.sock.close()
