"""The atlas's grid (solvers/atlas.py): the nearest points it finds are the nearest points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.solvers.arm import arm_state
from armd.solvers.atlas import G, make_atlas, nearest

ROOT = Path(__file__).resolve().parent.parent


def _brute(p: np.ndarray, t: np.ndarray, k: int) -> np.ndarray:
    return np.sort(((p - t) ** 2).sum(axis=1))[:k]


@pytest.mark.parametrize("name", ["insomniac", "desk4", "so101", "mycobot280"])
def test_nearest_is_the_scan(name: str) -> None:
    """Targets inside the atlas, beside its points, and far outside its grid: the same
    distances as sorting every point, for 1, 3, 8 and 20 of them."""
    robot = robots.load_folder(ROOT / "examples" / "arms" / name) if name == "mycobot280" else robots.load(name)
    atlas = arm_state(robot).atlas
    assert atlas.start[-1] == len(atlas.p) and np.all(np.diff(atlas.start) >= 0)
    rng = np.random.default_rng(5)
    near = atlas.p[rng.choice(len(atlas.p), 150)] + rng.normal(0.0, 0.01, (150, 3))
    targets = np.vstack([near, rng.uniform(-1.0, 1.0, (150, 3)), [[0.0, 0.0, 0.0], [5.0, -5.0, 5.0]]])
    for k in (1, 3, 8, 20):
        order = np.full(k, -1, dtype=np.int64)
        for t in targets:
            nearest(atlas, t, order)
            assert np.all(order >= 0)
            d = ((atlas.p[order] - t) ** 2).sum(axis=1)
            np.testing.assert_allclose(d, _brute(atlas.p, t, k), rtol=0, atol=1e-15)


def test_grid_of_few_points() -> None:
    """Fewer points than asked for: the rest of ``order`` stays -1; points all in one plane
    (a planar arm's atlas) and coincident points are indexed too."""
    p = np.array([[0.1, 0.0, 0.2], [0.3, 0.0, 0.2], [0.3, 0.0, 0.2]])
    atlas = make_atlas(np.zeros((3, 2)), p)
    assert atlas.start.shape == (G**3 + 1,)
    order = np.full(5, -1, dtype=np.int64)
    nearest(atlas, np.array([0.29, 0.0, 0.2]), order)
    assert sorted(atlas.p[order[:3], 0].tolist()) == [0.1, 0.3, 0.3] and np.all(order[3:] == -1)
