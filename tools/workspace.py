"""Workspace maps: where an arm's tool can go, drawn as seed 001 draws it.

A side view (the vertical plane the arm sweeps at yaw 0) with the area reachable at any tool
pitch (area A) and the area reachable with a level tool, a ``parallel`` approach (area B),
and a top view with the same two areas seen from above (reachable at some height). Every
cell is asked of the batch IK (:func:`solvers.reachable`, the same closed-form stage as
:func:`solvers.solve_ik_batch`) at the cell's centre.

``armd workspace ROBOT --out FILE.png`` draws it.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from armd import solvers
from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.types import FloatArray

BoolArray = NDArray[np.bool_]
Progress = Callable[[int, int], None]

BACKGROUND = (1.0, 1.0, 1.0)
AREA_A = (0.98, 0.70, 0.33)  # orange, as seed 001's area A
AREA_B = (0.50, 0.07, 0.17)  # maroon, as seed 001's area B
CHUNK = 20_000  # targets per batch IK call (progress is reported between chunks)


@dataclass(frozen=True)
class View:
    """One view: a grid of cell centres and, per cell, whether the tool reaches it.

    ``horizontal`` and ``vertical`` are the cell-centre coordinates [m] (x and z for the side
    view, x and y for the top view); ``any_pitch[i, j]`` is the cell at (horizontal[j],
    vertical[i]); ``parallel`` is None for an arm that cannot choose its tool pitch.
    """

    horizontal: FloatArray
    vertical: FloatArray
    any_pitch: BoolArray
    parallel: BoolArray | None

    @property
    def cell_area(self) -> float:
        return float((self.horizontal[1] - self.horizontal[0]) * (self.vertical[1] - self.vertical[0]))


@dataclass(frozen=True)
class Workspace:
    """An arm's workspace maps.

    Attributes:
        robot: the arm's name.
        step: cell size [m].
        lateral: y [m] of the side view's plane (the arm's plane at yaw 0: its pivot's offset).
        heights: the heights [m] the top view looks through (a cell is reachable when any is).
        side, top: the two views.
        seconds: time spent in the batch IK [s].
    """

    robot: str
    step: float
    lateral: float
    heights: FloatArray
    side: View
    top: View
    seconds: float


def _extent(robot: Robot, samples: int = 4096) -> tuple[float, float, float]:
    """Reach in the horizontal plane and the z range [m], from FK of in-limit configurations."""
    rng = np.random.default_rng(1)
    qs = rng.uniform(robot.limits.lower, robot.limits.upper, size=(samples, robot.nq))
    qs = qs[robot.limits.contains_batch(qs, tol=0.0)]
    pts = np.array([robot.fk(q) for q in qs])
    reach = float(np.max(np.hypot(pts[:, 0], pts[:, 1])))
    return reach, float(np.min(pts[:, 2])), float(np.max(pts[:, 2]))


def _axis(lo: float, hi: float, step: float) -> FloatArray:
    first = np.floor(lo / step) * step + step / 2
    return np.arange(first, hi + step / 2, step)


def compute(robot: Robot, *, step: float = 0.004, heights: int = 16, progress: Progress | None = None) -> Workspace:
    """The side and top views of ``robot``'s workspace, every ``step`` [m]."""
    if not (isinstance(step, (int, float)) and 0.0005 <= step <= 0.05):
        raise BadRequest(f"step must be in [0.0005, 0.05] m, got {step!r}", field="step")
    if not (isinstance(heights, int) and 1 <= heights <= 200):
        raise BadRequest(f"heights must be a whole number in [1, 200], got {heights!r}", field="heights")
    reach, zlo, zhi = _extent(robot)
    pad = 0.1 * max(reach, zhi - zlo)
    g = robot.geometry
    lateral = g.base[1] + g.pivot[1] if g is not None else 0.0  # (the plane the arm turns in, facing +x)
    xs = _axis(-reach - pad, reach + pad, step)
    zs = _axis(zlo - pad, zhi + pad, step)
    levels = np.linspace(zlo, zhi, heights)
    X, Z = np.meshgrid(xs, zs)
    side_pts = np.column_stack([X.ravel(), np.full(X.size, lateral), Z.ravel()])
    TX, TY, TZ = np.meshgrid(xs, xs, levels, indexing="ij")
    top_pts = np.column_stack([TX.ravel(), TY.ravel(), TZ.ravel()])
    has_pitch = _chooses_pitch(robot)
    approaches: list[object] = [None, "parallel"] if has_pitch else [None]
    total = (len(side_pts) + len(top_pts)) * len(approaches)
    done = 0
    started = time.perf_counter()

    def ask(points: FloatArray, approach: object) -> BoolArray:
        nonlocal done
        out = np.empty(len(points), dtype=bool)
        for k in range(0, len(points), CHUNK):
            out[k : k + CHUNK] = solvers.reachable(robot, points[k : k + CHUNK], approach=approach)
            done += len(points[k : k + CHUNK])
            if progress is not None:
                progress(done, total)
        return out

    side: list[BoolArray] = [ask(side_pts, a).reshape(X.shape) for a in approaches]
    top: list[BoolArray] = [
        np.any(ask(top_pts, a).reshape(TX.shape), axis=2).T  # rows: y, columns: x
        for a in approaches
    ]
    seconds = time.perf_counter() - started
    return Workspace(
        robot=robot.name,
        step=float(step),
        lateral=float(lateral),
        heights=levels,
        side=View(xs, zs, side[0], side[1] if has_pitch else None),
        top=View(xs, xs, top[0], top[1] if has_pitch else None),
        seconds=seconds,
    )


def _chooses_pitch(robot: Robot) -> bool:
    try:
        solvers.approach_pitch(robot, "parallel")
    except BadRequest:
        return False
    return True


def _image(view: View) -> FloatArray:
    img = np.empty((*view.any_pitch.shape, 3))
    img[:] = BACKGROUND
    img[view.any_pitch] = AREA_A
    if view.parallel is not None:
        img[view.parallel] = AREA_B
    return img


@dataclass(frozen=True)
class Drawn:
    """Where each view landed in the PNG: the axes' pixel box (left, bottom, right, top;
    pixels from the image's bottom-left corner) and the data limits it shows [m]."""

    side_box: tuple[float, float, float, float]
    side_limits: tuple[float, float, float, float]
    top_box: tuple[float, float, float, float]
    top_limits: tuple[float, float, float, float]
    size: tuple[int, int]  # width, height [px]

    @staticmethod
    def pixel(
        box: tuple[float, float, float, float],
        limits: tuple[float, float, float, float],
        h: float,
        v: float,
        height: int,
    ) -> tuple[int, int]:
        """Row and column in the image array (row 0 at the top) of the point (h, v) [m]."""
        x0, y0, x1, y1 = box
        h0, h1, v0, v1 = limits
        px = x0 + (h - h0) / (h1 - h0) * (x1 - x0)
        py = y0 + (v - v0) / (v1 - v0) * (y1 - y0)
        return int(height - py), int(px)


def plot(ws: Workspace, robot: Robot, out: str | Path, dpi: int = 100) -> Drawn:
    """Write the two views to a PNG; the arm drawn at its neutral pose (turned to face +x)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    fig, (ax_side, ax_top) = plt.subplots(1, 2, figsize=(13, 6), dpi=dpi)
    q = robot.neutral.copy()
    g = robot.geometry
    if g is not None:  # facing +x, where the side view is (the limits allowing)
        q[g.yaw] = min(max(-g.zero[0] / g.sign[0], robot.limits.lower[g.yaw]), robot.limits.upper[g.yaw])
    stick = robot.skeleton(q)
    half = ws.step / 2
    for ax, view, (a, b) in ((ax_side, ws.side, (0, 2)), (ax_top, ws.top, (0, 1))):
        limits = (
            float(view.horizontal[0] - half),
            float(view.horizontal[-1] + half),
            float(view.vertical[0] - half),
            float(view.vertical[-1] + half),
        )
        ax.imshow(_image(view), origin="lower", extent=limits, interpolation="nearest", aspect="equal")
        ax.plot(stick[:, a], stick[:, b], "-o", color="0.15", linewidth=2.5, markersize=4, label="arm (neutral)")
        ax.set_xlim(limits[0], limits[1])
        ax.set_ylim(limits[2], limits[3])
        ax.grid(True, alpha=0.25)
    area_a = ws.side.any_pitch.sum() * ws.side.cell_area
    ax_side.set_title(
        f"side view (plane y = {ws.lateral:.3f} m)\nA: {area_a * 1e4:.0f} cm²"
        + (f", B: {ws.side.parallel.sum() * ws.side.cell_area * 1e4:.0f} cm²" if ws.side.parallel is not None else "")
    )
    ax_side.set_xlabel("x [m]")
    ax_side.set_ylabel("z [m]")
    ax_top.set_title(f"top view (reachable at some height in [{ws.heights[0]:.3f}, {ws.heights[-1]:.3f}] m)")
    ax_top.set_xlabel("x [m]")
    ax_top.set_ylabel("y [m]")
    handles = [Patch(color=AREA_A, label="A: reachable at any tool pitch")]
    if ws.side.parallel is not None and robot.geometry is not None and robot.geometry.level:
        handles.append(Patch(color=AREA_B, label="B = A: a linkage keeps the tool level"))
    elif ws.side.parallel is not None:
        handles.append(Patch(color=AREA_B, label="B: reachable with a level tool (parallel)"))
    else:
        handles.append(Patch(color=BACKGROUND, label="(no wrist: the tool pitch follows the position)"))
    fig.legend(handles=handles, loc="lower center", ncol=2)
    fig.suptitle(f"{robot.name}: {robot.title} — workspace, {ws.step * 1000:g} mm cells")
    fig.tight_layout(rect=(0, 0.06, 1, 0.96))
    fig.canvas.draw()
    drawn = Drawn(
        side_box=tuple(ax_side.get_window_extent().extents),
        side_limits=(*ax_side.get_xlim(), *ax_side.get_ylim()),
        top_box=tuple(ax_top.get_window_extent().extents),
        top_limits=(*ax_top.get_xlim(), *ax_top.get_ylim()),
        size=(int(fig.bbox.width), int(fig.bbox.height)),
    )
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return drawn


class ProgressBar:
    """A text progress bar on stderr, shown only once the work has taken more than a moment
    (redrawn in place on a terminal; a few lines otherwise)."""

    def __init__(self, label: str, after: float = 0.5, width: int = 30) -> None:
        self.label, self.after, self.width = label, after, width
        self.started = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last = -1

    def __call__(self, done: int, total: int) -> None:
        if self.last < 0 and time.perf_counter() - self.started < self.after and done < total:
            return
        step = 1 if self.tty else 25  # percent between redraws
        percent = 100 * done // total
        if percent // step == self.last // step and done < total:
            return
        self.last = percent
        filled = self.width * done // total
        bar = f"{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {percent:3d}%"
        sys.stderr.write(("\r" + bar + ("\n" if done >= total else "")) if self.tty else bar + "\n")
        sys.stderr.flush()
