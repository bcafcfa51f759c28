"""`cellguard sim-server`: a simulated cell served as a robot on 127.0.0.1, on wall time."""

from __future__ import annotations

import typer

from cellguard.cli.app import app
from cellguard.cli.errors import fail
from cellguard.errors import CellguardError, ConfigError


@app.command("sim-server")
def sim_server(
    cell: str = typer.Argument(..., help="Registered cell name, e.g. arm-pick-place."),
    port: int = typer.Option(..., "--port", help="UDP port on 127.0.0.1 (1-65535)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the cell's random generator."),
    delay_ms: float = typer.Option(0.0, "--delay-ms", help="Hold every state packet back this long (link tests)."),
    drop_every: int = typer.Option(0, "--drop-every", help="Lose every n-th state packet (link tests); 0: none."),
    duration_s: float | None = typer.Option(None, "--duration-s", help="Stop after this long; default: until killed."),
    rate_hz: float | None = typer.Option(None, "--rate-hz", help="Servo rate (50-1000 Hz); default: the physics step."),
) -> None:
    """Serve a simulated cell as a robot in its own process (stepping on wall time)."""
    from cellguard.runtime.sim_server import serve

    try:
        if not 1 <= port <= 65535:
            raise ConfigError(f"--port: must be in 1..65535, got {port}")
        if delay_ms < 0 or drop_every < 0 or seed < 0:
            raise ConfigError("--delay-ms, --drop-every, --seed: must be >= 0")
        if rate_hz is not None and not 50.0 <= rate_hz <= 1000.0:
            raise ConfigError(f"--rate-hz: must be in 50..1000, got {rate_hz}")
        serve(cell, port, seed=seed, delay_ms=delay_ms, drop_every=drop_every, duration_s=duration_s, rate_hz=rate_hz)
    except CellguardError as exc:
        fail(exc)
    except OSError as exc:
        fail(ConfigError(f"--port: cannot listen on udp://127.0.0.1:{port} ({exc.strerror})"))
    except KeyboardInterrupt:
        pass
