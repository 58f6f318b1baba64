"""Collision benchmark: one configuration checked against the arm itself and its floor.

Per catalogue arm, ``--n`` random configurations within the box limits (the same for each
measure): ``robot.collision.first_contact(q)`` (Pinocchio's geometry placements and coal's
narrow phase over every checked pair, stopping at the first contact), alone and with three
boxes around the arm (the issue's case), beside ``robot.fk(q)`` (Pinocchio's forward
kinematics and the tool frame alone) in the same run, each call timed with perf_counter_ns.
Reported: median and p99 [us], the fraction of configurations in collision, and the pairs
checked. Issue 17's bar: one configuration (self + ground + three boxes) <= 20 us.

Run: ``.venv/bin/python bench/collision.py [--n 5000]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from armd import robots
from armd.robots.collision import Obstacle


def timed(fn: object, qs: np.ndarray) -> np.ndarray:
    out = np.empty(len(qs))
    for i, q in enumerate(qs):
        t = time.perf_counter_ns()
        fn(q)  # type: ignore[operator]
        out[i] = (time.perf_counter_ns() - t) / 1e3
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5000, help="configurations per arm (default 5,000)")
    args = ap.parse_args()
    print("| arm | world | pairs | in collision | check: median | p99 | fk alone: median | p99 |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for name in robots.names():
        arm = robots.load(name)
        assert arm.collision is not None
        rng = np.random.default_rng(sum(name.encode()))
        qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(args.n, arm.nq))
        for world, cm in (("floor", arm.collision), ("floor + 3 boxes", arm.collision.with_obstacles(boxes(arm)))):
            for q in qs[:50]:  # warm up
                cm.first_contact(q)
                arm.fk(q)
            check = timed(cm.first_contact, qs)
            fk = timed(arm.fk, qs)
            hits = sum(cm.first_contact(q) is not None for q in qs) / len(qs)
            print(
                f"| {name} | {world} | {len(cm.pairs)} | {hits:.0%} | {np.median(check):.1f} "
                f"| {np.percentile(check, 99):.1f} | {np.median(fk):.1f} | {np.percentile(fk, 99):.1f} |"
            )


def boxes(arm: robots.Robot) -> list[Obstacle]:
    """Three 6 cm boxes around the arm at the tool's neutral height, left, right and behind,
    as near as the neutral pose leaves them clear."""
    assert arm.collision is not None
    p = arm.fk(arm.neutral)
    r = max(float(np.hypot(p[0], p[1])), 0.1)
    for k in (0.8, 1.2, 1.6, 2.4):
        out = [
            Obstacle(f"box{i}", "box", (0.06, 0.06, 0.06), (k * r * c, k * r * s, float(p[2])))
            for i, (c, s) in enumerate(((0.0, 1.0), (0.0, -1.0), (-1.0, 0.0)))
        ]
        if arm.collision.with_obstacles(out).first_contact(arm.neutral) is None:
            return out
    raise RuntimeError(f"{arm.name}: no place for the boxes")


if __name__ == "__main__":
    main()
