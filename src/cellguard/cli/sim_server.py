"""`cellguard sim-server`: a simulated cell served as a robot on 127.0.0.1, on wall time."""

from __future__ import annotations

import typer

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.errors import CellguardError, ConfigError

WEEK_S = 7 * 24 * 3600


def _within(option: str, value: float | None, low: float, high: float) -> None:
    """ConfigError unless ``low <= value <= high`` (None: not given). NaN fails both comparisons and an
    infinity the finite bound, so neither reaches the server (where they raised mid-start)."""
    if value is not None and not low <= value <= high:
        raise ConfigError(f"{option}: must be in {low}..{high}, got {value}")


@app.command("sim-server")
def sim_server(
    cell: str = typer.Argument(..., help="Registered cell name, e.g. arm-pick-place."),
    port: int = typer.Option(..., "--port", help="UDP port on 127.0.0.1 (1-65535)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the cell's random generator (0 to 2^32-1)."),
    delay_ms: float = typer.Option(0.0, "--delay-ms", help="Hold every state packet back this long, 0-1000 ms "
                                   "(link tests)."),
    drop_every: int = typer.Option(0, "--drop-every", help="Lose every n-th state packet, 0-1000000 (link tests); "
                                   "0: none."),
    duration_s: float | None = typer.Option(None, "--duration-s", help="Stop after this long, 0.001-604800 s (a "
                                            "week); default: until killed."),
    rate_hz: float | None = typer.Option(None, "--rate-hz", help="Servo rate, 50-1000 Hz, served within 1 % as whole "
                                         "physics steps of the cell (1 ms: 1000, 500, 333.3, 250, ... 50 Hz); "
                                         "default: the physics step."),
) -> None:
    """Serve a simulated cell as a robot in its own process (stepping on wall time)."""
    from cellguard.runtime.sim_server import serve

    try:
        _within("--port", port, 1, 65535)
        _within("--seed", seed, 0, 2**32 - 1)
        _within("--delay-ms", delay_ms, 0, 1000)
        _within("--drop-every", drop_every, 0, 1_000_000)
        _within("--duration-s", duration_s, 0.001, WEEK_S)
        _within("--rate-hz", rate_hz, 50, 1000)
        serve(cell, port, seed=seed, delay_ms=delay_ms, drop_every=drop_every, duration_s=duration_s, rate_hz=rate_hz)
    except CellguardError as exc:
        fail(exc)
    except OSError as exc:
        fail(ConfigError(f"--port: cannot listen on udp://127.0.0.1:{port} ({exc.strerror})"))
    except KeyboardInterrupt:
        pass
