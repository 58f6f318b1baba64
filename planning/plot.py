"""Trajectory plots: position, velocity, acceleration and jerk per joint, limits drawn as lines.

Uses matplotlib's Agg backend (no display needed). Called by ``armd plot``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from robots import Robot

from .trajectory import Trajectory


def plot_trajectory(traj: Trajectory, robot: Robot, out: str | Path, title: str | None = None) -> Path:
    """Write a PNG of ``traj`` to ``out``: one row per quantity, one colour per joint; dashed
    lines at each joint's limits (position limits, and +-vmax, +-amax, +-jmax)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lim = robot.limits
    rows = [
        ("position [rad]", traj.position, (lim.lower, lim.upper)),
        ("velocity [rad/s]", traj.velocity, (-lim.velocity, lim.velocity)),
        ("acceleration [rad/s²]", traj.acceleration, (-lim.acceleration, lim.acceleration)),
        ("jerk [rad/s³]", traj.jerk, (-lim.jerk, lim.jerk)),
    ]
    fig, axes = plt.subplots(len(rows), 1, figsize=(10, 11), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (label, values, (lo, hi)) in zip(axes, rows, strict=True):
        for j, name in enumerate(traj.joint_names):
            c = colours[j % len(colours)]
            ax.plot(traj.times, values[:, j], color=c, label=name, linewidth=1.6)
            ax.axhline(float(lo[j]), color=c, linestyle="--", linewidth=0.8, alpha=0.7)
            ax.axhline(float(hi[j]), color=c, linestyle="--", linewidth=0.8, alpha=0.7)
        span = float(np.max(np.abs(values))) if values.size else 1.0
        limit = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
        top = 1.15 * max(span, min(limit, 3.0 * span if span > 0 else limit))
        if label.startswith("position"):
            ax.set_ylim(float(np.min(lo)) - 0.1, float(np.max(hi)) + 0.1)
        else:
            ax.set_ylim(-top, top)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8, ncol=min(len(traj.joint_names), 5))
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title or f"{traj.robot}: {traj.path} trajectory, {traj.duration:.2f} s at {traj.rate_hz:g} Hz "
                 "(dashed: limits)")
    fig.tight_layout()
    path = Path(out)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
