"""Compiled collision benchmark: one configuration checked by the compiled stage beside coal.

Per catalogue arm and world (its floor; its floor and bench/collision.py's three boxes),
``--n`` random configurations within the box limits, the same for every measure, each timed
with perf_counter_ns:

- coal: ``robot.collision.first_contact(q)`` (Pinocchio's geometry placements and coal's narrow
  phase over the checked pairs, stopping at the first contact: one Python call, as armd checks
  today);
- compiled, from Python: :meth:`armd.solvers.world.CompiledWorld.first_contact` (one call into
  the compiled code, the arm's arrays handed over included);
- compiled, in compiled code: :func:`armd.solvers.collide.first_collisions` on ``--repeat``
  copies of the configuration, over ``--repeat``: what a compiled caller (the IK's branch loop,
  the planner's samples) pays a configuration;

and the same three for the clearance (``CollisionModel.clearance``: coal's distances over every
pair; :meth:`CompiledWorld.clearance`; :func:`armd.solvers.collide.min_distances`).
Reported: median and p99 [us] and the fraction in collision; the answers are checked to agree
(the first pair in contact; the clearance to coal's tolerance).

Run: ``.venv/bin/python bench/collision_compiled.py [--n 5000] [--repeat 32]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from armd import robots
from armd.robots.collision import CollisionModel
from armd.solvers import jit
from armd.solvers.collide import first_collisions, min_distances
from armd.solvers.packed import Packed
from armd.solvers.world import compile_world
from bench.collision import boxes, timed


def in_compiled_code(shapes: Packed, qs: np.ndarray, nearest: bool, repeat: int) -> np.ndarray:
    """Each configuration's time [us] inside one compiled call over ``repeat`` copies of it (its
    first contact; ``nearest``: its clearance)."""
    out = np.empty(len(qs))
    index, distance = np.empty(repeat, dtype=np.int64), np.empty(repeat)
    for i, q in enumerate(qs):
        Q = np.ascontiguousarray(np.broadcast_to(q, (repeat, len(q))))
        t = time.perf_counter_ns()
        if nearest:
            min_distances(shapes, Q, distance, index)
        else:
            first_collisions(shapes, Q, index)
        out[i] = (time.perf_counter_ns() - t) / 1e3 / repeat
    return out


def row(name: str, world: str, cm: CollisionModel, qs: np.ndarray, repeat: int) -> tuple[str, str]:
    """The two table rows (first contact, clearance) of one arm in one world."""
    cw = compile_world(cm)
    assert not cw.on_coal, f"{name}: pairs left to coal: {cw.on_coal}"
    for q in qs[:50]:  # warm up
        cm.first_contact(q), cw.first_contact(q), cm.clearance(q), cw.clearance(q)
    in_compiled_code(cw.packed_shapes, qs[:5], False, repeat)
    in_compiled_code(cw.packed_shapes, qs[:5], True, repeat)
    hits = sum(cw.first_contact(q) is not None for q in qs) / len(qs)
    mismatched = sum(cw.first_contact(q) != cm.first_contact(q) for q in qs)
    cells = []
    for nearest, coal_fn, compiled_fn in (
        (False, cm.first_contact, cw.first_contact),
        (True, cm.clearance, cw.clearance),
    ):
        coal = timed(coal_fn, qs)
        from_python = timed(compiled_fn, qs)
        inside = in_compiled_code(cw.packed_shapes, qs, nearest, repeat)
        cells.append(
            f"| {name} | {world} | {len(cm.pairs)} | {hits:.0%} "
            f"| {np.median(coal):.2f} | {np.percentile(coal, 99):.2f} "
            f"| {np.median(from_python):.2f} | {np.percentile(from_python, 99):.2f} "
            f"| {np.median(inside):.3f} | {np.percentile(inside, 99):.3f} "
            f"| {np.median(coal) / np.median(inside):.0f}x | {mismatched} |"
        )
    return cells[0], cells[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000, help="configurations per arm and world (default 5,000)")
    ap.add_argument("--repeat", type=int, default=32, help="copies of a configuration a compiled call (default 32)")
    args = ap.parse_args()
    print(f"compiled code: {'the native build' if jit.NATIVE is not None else 'Numba JIT'}")
    firsts, clearances = [], []
    for name in robots.names():
        arm = robots.load(name)
        assert arm.collision is not None
        rng = np.random.default_rng(sum(name.encode()))
        qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(args.n, arm.nq))
        for world, cm in (("floor", arm.collision), ("floor + 3 boxes", arm.collision.with_obstacles(boxes(arm)))):
            first, clearance = row(name, world, cm, qs, args.repeat)
            firsts.append(first)
            clearances.append(clearance)
    header = (
        "| arm | world | pairs | in collision | coal: median us | p99 | compiled from Python: median us | p99 "
        "| in compiled code: median us | p99 | coal / in compiled code | first pairs unlike coal's |"
    )
    rule = "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    for title, rows in (("First contact (first_contact)", firsts), ("Clearance (the nearest pair)", clearances)):
        print(f"\n{title}\n\n{header}\n{rule}")
        print("\n".join(rows))


if __name__ == "__main__":
    main()
