"""Workspace maps: the picture shows what the IK answers.

Each sampled cell's colour in the PNG is read back and compared with the single-target
``solve_ik`` (a different path through the solver than the batch stage that made the map) at
the cell's centre.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from armd import robots, solvers
from armd.cli import main
from armd.errors import BadRequest
from armd.tools import workspace
from armd.tools.workspace import AREA_A, AREA_B, BACKGROUND, Drawn

ARMS = ["insomniac", "sg5ut", "gupta3", "desk4"]
COLOURS = {"none": BACKGROUND, "A": AREA_A, "B": AREA_B}


def _colour_at(img: np.ndarray, drawn: Drawn, side: bool, h: float, v: float) -> str | None:
    box, limits = (drawn.side_box, drawn.side_limits) if side else (drawn.top_box, drawn.top_limits)
    row, col = Drawn.pixel(box, limits, h, v, img.shape[0])
    rgb = img[row, col, :3]
    name, dist = min(((k, float(np.max(np.abs(rgb - np.array(c))))) for k, c in COLOURS.items()), key=lambda kv: kv[1])
    return name if dist < 0.03 else None  # a line drawn over the cell, say: not a fill colour


def _ok(arm: robots.Robot, point: list[float], approach: object) -> bool:
    return solvers.solve_ik(arm, point, approach=approach).status == "ok"


@pytest.mark.parametrize("name", ARMS)
def test_the_picture_agrees_with_the_ik(name: str, tmp_path: Path) -> None:
    import matplotlib.image

    arm = robots.load(name)
    ws = workspace.compute(arm, step=0.012, heights=5)
    out = tmp_path / f"{name}.png"
    drawn = workspace.plot(ws, arm, out)
    img = matplotlib.image.imread(out)
    assert img.shape[:2] == (drawn.size[1], drawn.size[0])
    chooses_pitch = ws.side.parallel is not None
    assert chooses_pitch == (name != "gupta3")  # gupta3 has no wrist: no area B
    rng = np.random.default_rng(7)
    checked = {"A": 0, "B": 0, "none": 0}
    unreadable = 0
    for side, view in ((True, ws.side), (False, ws.top)):
        inside = np.argwhere(view.any_pitch)
        outside = np.argwhere(~view.any_pitch)
        assert len(inside) and len(outside)
        picks = [
            *inside[rng.choice(len(inside), 14, replace=False)],
            *outside[rng.choice(len(outside), 6, replace=False)],
        ]
        for i, j in picks:
            h, v = float(view.horizontal[j]), float(view.vertical[i])
            points = [[h, ws.lateral, v]] if side else [[h, v, float(z)] for z in ws.heights]
            truth_a = any(_ok(arm, p, None) for p in points)
            truth_b = chooses_pitch and any(_ok(arm, p, "parallel") for p in points)
            expected = "B" if truth_b else ("A" if truth_a else "none")
            seen = _colour_at(img, drawn, side, h, v)
            if seen is None:
                unreadable += 1
                continue
            assert seen == expected, (
                f"{name} {'side' if side else 'top'} cell at ({h:.3f}, {v:.3f}): "
                f"picture says {seen}, solve_ik says {expected}"
            )
            checked[seen] += 1
    assert unreadable <= 4
    assert checked["A"] + checked["B"] >= 20 and checked["none"] >= 8
    if chooses_pitch:
        assert checked["B"] > 0


def test_level_linkage_makes_b_equal_a() -> None:
    ws = workspace.compute(robots.load("desk4"), step=0.02, heights=3)
    assert ws.side.parallel is not None and np.array_equal(ws.side.parallel, ws.side.any_pitch)


def test_b_is_inside_a_and_smaller_for_a_wrist_arm() -> None:
    ws = workspace.compute(robots.load("insomniac"), step=0.02, heights=3)
    assert ws.side.parallel is not None
    assert not np.any(ws.side.parallel & ~ws.side.any_pitch)
    assert 0 < ws.side.parallel.sum() < ws.side.any_pitch.sum()


def test_cli_writes_the_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ws.png"
    assert main(["workspace", "sg5ut", "--out", str(out), "--step", "0.02", "--heights", "3"]) == 0
    assert out.stat().st_size > 10_000
    line = capsys.readouterr().out
    assert "sg5ut workspace" in line and "A " in line and "B " in line


@pytest.mark.parametrize(
    "argv",
    [
        ["workspace", "nosuch"],
        ["workspace", "sg5ut", "--step", "0"],
        ["workspace", "sg5ut", "--step", "1"],
        ["workspace", "sg5ut", "--heights", "0"],
    ],
)
def test_cli_bad_input_is_an_error(argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ws.png"
    assert main([*argv, "--out", str(out)]) == 1
    assert "armd: error:" in capsys.readouterr().err
    assert not out.exists()


def test_reachable_matches_the_batch_statuses() -> None:
    rng = np.random.default_rng(3)
    for name in ARMS:
        arm = robots.load(name)
        pts = rng.uniform(-0.4, 0.4, size=(400, 3)) + np.array([0.0, 0.0, 0.15])
        mask = solvers.reachable(arm, pts)
        assert np.array_equal(mask, solvers.solve_ik_batch(arm, pts).status == "ok")
        assert 0 < mask.sum() < len(mask)
    with pytest.raises(BadRequest):
        solvers.reachable(robots.load("gupta3"), [[0.1, 0.0, 0.1]], approach="parallel")
    with pytest.raises(BadRequest):
        solvers.reachable(robots.load("sg5ut"), [[0.1, 0.0, float("nan")]])
