"""Robot bridges by scheme: a plain dict from scheme to factory, each bridge one module.

A scenario's ``robot: SCHEME:ARGUMENT`` (``sim-server:udp://127.0.0.1:PORT``, ``lerobot:TYPE?...``)
is parsed once into a ``BridgeSpec``; the factory gets it and the scenario. A bridge has every member
of the ``Robot`` protocol (``name``, ``profile``, ``dt_ns``, ``read``, ``write``, ``safety``, ``set_power``,
``observe``, ``context``); its failures raise ``RobotLinkError``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from cellguard.errors import ConfigError, ScenarioError, UnknownNameError
from cellguard.robot.protocol import Robot


@dataclass(frozen=True)
class BridgeSpec:
    """``robot: SCHEME:ARGUMENT`` split at the first colon."""

    scheme: str
    argument: str


def _sim_server(spec: BridgeSpec, scenario):
    from cellguard.robot.bridges.sim_server import connect_sim_server

    return connect_sim_server(spec, scenario)


def _lerobot(spec: BridgeSpec, scenario):
    from cellguard.robot.bridges.lerobot import make_lerobot_robot

    if scenario is None:  # a bridge built on its own, as LeRobot's tools and the tests build one
        return make_lerobot_robot(spec.argument)
    return make_lerobot_robot(spec.argument, scenario.realtime.read_timeout_s, cell=scenario.cell)


BRIDGES: dict[str, Callable[[BridgeSpec, object], object]] = {"sim-server": _sim_server, "lerobot": _lerobot}


def parse_bridge(text: str) -> BridgeSpec:
    scheme, sep, argument = text.partition(":")
    if not sep or not argument:
        raise ScenarioError(f"robot: expected 'sim' or SCHEME:ARGUMENT, got {text!r}")
    return BridgeSpec(scheme, argument)


def make_bridge(text: str, scenario):
    """Connect the bridge ``text`` names; an unknown scheme lists the known ones. A bridge that lacks a member of
    ``Robot`` (one written to a shorter list) is closed and refused in one line, not an AttributeError mid-run."""
    from cellguard.robot.registry import from_plugin

    spec = parse_bridge(text)
    try:
        factory = BRIDGES[spec.scheme]
    except KeyError:
        raise UnknownNameError("robot bridge", spec.scheme, list(BRIDGES)) from None
    robot = factory(spec, scenario)
    try:
        return from_plugin(lambda: robot, Robot, f"robot bridge {spec.scheme!r}")
    except ConfigError:
        close = getattr(robot, "close", None)  # a link it opened (a sim-server holds the session until goodbye)
        if callable(close):
            close()
        raise
