"""Trajectory plots: a PNG with the four quantities and the limits, from Python and the CLI."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from armd import planning, robots
from armd.tools.plot import plot_reply, plot_trajectory

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent


def test_plot_writes_a_png_with_content(tmp_path: Path) -> None:
    import matplotlib.image as mpimg

    arm = robots.load("sg5ut")
    traj = planning.plan(arm, arm.neutral, [0.5, 1.2, -0.8, -0.3])
    out = plot_trajectory(traj, arm, tmp_path / "t.png")
    img = mpimg.imread(out)
    assert img.shape[0] > 500 and img.shape[1] > 500
    rgb = img[..., :3]
    coloured = np.any(np.abs(rgb - rgb.mean(axis=2, keepdims=True)) > 0.1, axis=2)  # not grey: curves
    assert coloured.mean() > 0.005


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "armd.cli", *args], capture_output=True, text=True, cwd=ROOT, timeout=300
    )


def test_cli_plot(tmp_path: Path) -> None:
    out = tmp_path / "line.png"
    r = run("plot", "insomniac", "--target", "0.25", "0.05", "0.2", "--path", "line", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 10_000 and "line trajectory of insomniac" in r.stdout


def test_cli_plot_errors(tmp_path: Path) -> None:
    r = run("plot", "gupta3", "--goal", "0", "1", "-1", "--target", "0.1", "0", "0.1", "--out", str(tmp_path / "x.png"))
    assert r.returncode == 1 and "exactly one of" in r.stderr
    r = run("plot", "gupta3", "--goal", "0", "1", "0.5", "--out", str(tmp_path / "x.png"))
    assert r.returncode == 1 and "elbow" in r.stderr and "Traceback" not in r.stderr
    r = run("plot", "nosuch", "--goal", "0", "--out", str(tmp_path / "x.png"))
    assert r.returncode == 1 and "unknown robot" in r.stderr
    assert not (tmp_path / "x.png").exists()


def test_client_plots_a_planned_trajectory(client: object, router: str, tmp_path: Path) -> None:
    """plot_reply: the service's samples and limits (from ``info``) drawn; the same picture
    as the planner's own plot of the same plan."""
    import matplotlib.image as mpimg

    from armd.clients import ArmClient

    assert isinstance(client, ArmClient)
    arm = robots.load("sg5ut")
    goal = [0.5, 1.2, -0.8, -0.3]
    reply = client.plan("sg5ut", goal, start=arm.neutral)
    out = plot_reply(client, "sg5ut", reply, tmp_path / "c.png", title="same")  # type: ignore[arg-type]
    local = plot_trajectory(planning.plan(arm, arm.neutral, goal), arm, tmp_path / "l.png", title="same")
    a, b = mpimg.imread(out), mpimg.imread(local)
    assert a.shape == b.shape
    assert np.mean(np.abs(a - b)) < 1e-3  # same samples, same limits, same drawing


def test_cli_plan_plot(client: object, router: str, tmp_path: Path, capsys: object) -> None:
    from armd.cli import main

    out = tmp_path / "plan.png"
    assert (
        main(
            [
                "plan",
                "insomniac",
                "--target",
                "0.25",
                "0.05",
                "0.2",
                "--start",
                "0",
                "1.2",
                "-1.2",
                "0",
                "0",
                "--plot",
                str(out),
                "--connect",
                router,
            ]
        )
        == 0
    )
    assert out.stat().st_size > 10_000
