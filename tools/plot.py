"""Trajectory plots: position, velocity, acceleration and jerk per joint, limits drawn as lines.

Uses matplotlib's Agg backend (no display needed). :func:`plot_trajectory` draws a planned
:class:`~armd.planning.Trajectory` (``armd plot``); :func:`plot_reply` a ``plan`` reply from the
service, with the limits asked of it (``armd plan --plot``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from armd.clients import ArmClient, TrajectoryReply
from armd.planning.trajectory import Trajectory, forward_jerk
from armd.robots import Robot
from armd.robots.types import FloatArray


def plot_trajectory(traj: Trajectory, robot: Robot, out: str | Path, title: str | None = None) -> Path:
    """Write a PNG of ``traj`` to ``out``: one row per quantity, one colour per joint; dashed
    lines at each joint's limits (position limits, and +-vmax, +-amax, +-jmax)."""
    lim = robot.limits
    return plot_samples(
        out,
        traj.joint_names,
        traj.times,
        traj.position,
        traj.velocity,
        traj.acceleration,
        traj.jerk,
        lower=lim.lower,
        upper=lim.upper,
        vmax=lim.velocity,
        amax=lim.acceleration,
        jmax=lim.jerk,
        title=title
        or f"{traj.robot}: {traj.path} trajectory, {traj.duration:.2f} s at {traj.rate_hz:g} Hz (dashed: limits)",
    )


def plot_reply(
    client: ArmClient, robot: str, trajectory: TrajectoryReply, out: str | Path, title: str | None = None
) -> Path:
    """Write a PNG of a trajectory the service planned (position, velocity, acceleration, jerk
    per joint), the arm's limits, asked of the service (``info``), drawn as dashed lines."""
    joints = client.info(robot)["joints"]
    by_name = {j["name"]: j for j in joints}
    limit = {
        k: np.array([by_name[n][k] for n in trajectory.joint_names], dtype=float)
        for k in ("lower", "upper", "velocity", "acceleration", "jerk")
    }
    t = trajectory
    return plot_samples(
        out,
        t.joint_names,
        t.times,
        t.position,
        t.velocity,
        t.acceleration,
        forward_jerk(t.acceleration, 1.0 / t.rate_hz),
        lower=limit["lower"],
        upper=limit["upper"],
        vmax=limit["velocity"],
        amax=limit["acceleration"],
        jmax=limit["jerk"],
        title=title or f"{robot}: {t.path} trajectory, {t.duration:.2f} s at {t.rate_hz:g} Hz (dashed: limits)",
    )


def plot_samples(
    out: str | Path,
    joint_names: Sequence[str],
    times: FloatArray,
    position: FloatArray,
    velocity: FloatArray,
    acceleration: FloatArray,
    jerk: FloatArray,
    *,
    lower: FloatArray,
    upper: FloatArray,
    vmax: FloatArray,
    amax: FloatArray,
    jmax: FloatArray,
    title: str,
) -> Path:
    """The plot of :func:`plot_trajectory` from bare samples (k, n) and per-joint limits (n,)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [
        ("position [rad]", position, (lower, upper)),
        ("velocity [rad/s]", velocity, (-vmax, vmax)),
        ("acceleration [rad/s²]", acceleration, (-amax, amax)),
        ("jerk [rad/s³]", jerk, (-jmax, jmax)),
    ]
    fig, axes = plt.subplots(len(rows), 1, figsize=(10, 11), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (label, values, (lo, hi)) in zip(axes, rows, strict=True):
        for j, name in enumerate(joint_names):
            c = colours[j % len(colours)]
            ax.plot(times, values[:, j], color=c, label=name, linewidth=1.6)
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
    axes[0].legend(loc="upper right", fontsize=8, ncol=min(len(joint_names), 5))
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(out)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
