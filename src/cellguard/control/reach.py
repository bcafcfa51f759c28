"""Reach: how far the tool point moves per unit of each joint, the tool Jacobian's column norms [m/rad or m/m].

The guard knows the tool only as a callable (joint positions (D,) -> tool point (3,) [m]), so the
columns come from forward differences. Whatever the joint velocities' signs, the tool speed is at
most sum_j reach_j |v_j|: joints driven one by one (ruckig, unsynchronised) cannot be credited with
cancelling each other's tool motion, as a reference's own motion may. Two uses: a tool-speed cap
in joint terms at the setpoint (``ToolCap``, only on the ticks where the cap binds), and each
joint's largest reach anywhere in its range, per axis (``max_reach``, once per guard), which
bounds the tool path while the joints move: |x_k(q') - x_k(q)| <= sum_j max_reach_kj |q'_j - q_j|.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

STEP = 1e-6  # forward-difference step [rad or m]: truncation and rounding both near 1e-6 of the reach
MARGIN = 1.2  # the sampled maximum is raised by this factor: no sample lands exactly on the worst pose
SAMPLES = 256  # poses drawn over the joint ranges for ``max_reach``


def columns_at(tool: Callable[[np.ndarray], np.ndarray], q: np.ndarray, tip) -> list[tuple[float, float, float]]:
    """The tool Jacobian's columns at ``q`` [m/unit], one (x, y, z) per joint; ``tip`` is ``tool(q)``."""
    x0, y0, z0 = tip
    out = []
    probe = np.array(q, dtype=np.float64)
    for j in range(len(probe)):
        held = probe[j]
        probe[j] = held + STEP
        x, y, z = tool(probe).tolist()
        probe[j] = held
        out.append(((x - x0) / STEP, (y - y0) / STEP, (z - z0) / STEP))
    return out


def reach_at(tool: Callable[[np.ndarray], np.ndarray], q: np.ndarray, tip) -> list[float]:
    """Per joint, |d tool / d q_j| at ``q`` (D plain floats); ``tip`` is ``tool(q)``, already known."""
    return [math.sqrt(x * x + y * y + z * z) for x, y, z in columns_at(tool, q, tip)]


@dataclass(frozen=True)
class MaxReach:
    """Upper estimates of the tool Jacobian anywhere in a joint range [m/unit]: per axis x, y, z and joint,
    |d tool_k / d q_j| (``axes``, 3 lists of D plain floats); per joint, the column's norm (``norm``, D)."""

    axes: list[list[float]]
    norm: list[float]


def max_reach(tool: Callable[[np.ndarray], np.ndarray], lo: np.ndarray, hi: np.ndarray) -> MaxReach:
    """The largest at ``SAMPLES`` poses drawn in [lo, hi] with a fixed seed, times ``MARGIN``. Per axis too,
    because the walls of a box are: a joint on a vertical axis moves the tool along no wall's normal but the
    side walls'."""
    rng = np.random.default_rng(0)
    axes, norm = np.zeros((3, len(lo))), np.zeros(len(lo))
    for q in rng.uniform(lo, hi, (SAMPLES, len(lo))):
        columns = np.array(columns_at(tool, q, tool(q).tolist())).T
        axes, norm = np.maximum(axes, np.abs(columns)), np.maximum(norm, np.linalg.norm(columns, axis=0))
    return MaxReach((axes * MARGIN).tolist(), (norm * MARGIN).tolist())


@dataclass(frozen=True)
class ToolCap:
    """A tool-speed cap of ``limit`` [m/s] in joint terms: the joints' ``reach`` at the setpoint (D plain floats)."""

    limit: float
    reach: list[float]
