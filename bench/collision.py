"""Collision benchmark: one configuration checked against the arm itself and its floor.

Per catalogue arm, ``--n`` random configurations within the box limits (the same for each
measure): ``robot.collision.first_contact(q)`` (Pinocchio's geometry placements and coal's
narrow phase over every checked pair, stopping at the first contact), alone and with three
boxes around the arm (the issue's case), beside ``robot.fk(q)`` (Pinocchio's forward
kinematics and the tool frame alone) in the same run, each call timed with perf_counter_ns.
Reported: median and p99 [us], the fraction of configurations in collision, and the pairs
checked. Issue 17's bar: one configuration (self + ground + three boxes) <= 20 us.

Then IK with the check beside the same IK without it (the arm without its world), in the same
run: ``solve_ik`` on the tool points of ``--ik`` random configurations clear of the floor, the
arm and three boxes (reachable, collision-free targets, seeded from neutral), each timed.
Issue 17's bar: <= 30 us median with the check.

Run: ``.venv/bin/python bench/collision.py [--n 5000] [--ik 2000]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from armd import robots, solvers
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
    ap.add_argument("--ik", type=int, default=2000, help="IK targets per arm (default 2,000)")
    args = ap.parse_args()
    check_table(args.n)
    print()
    ik_table(args.ik)


def ik_table(n: int) -> None:
    print("| arm | world | IK with the check: median us | p99 | without it: median us | p99 | ok |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name in robots.names():
        arm = robots.load_folder(robots.CATALOGUE_DIR / name)
        assert arm.collision is not None
        arm.collision = arm.collision.with_obstacles(boxes(arm))
        plain = robots.load_folder(robots.CATALOGUE_DIR / name)
        plain.collision = None
        rng = np.random.default_rng(sum(name.encode()) + 1)
        targets = []
        while len(targets) < n:
            q = rng.uniform(arm.limits.lower, arm.limits.upper)
            if arm.limits.contains(q) and arm.collision.first_contact(q) is None and arm.fk(q)[2] >= 0.0:
                targets.append(arm.fk(q))
        for t in targets[:50]:  # warm up
            solvers.solve_ik(arm, t)
            solvers.solve_ik(plain, t)
        with_check = timed(lambda t, a=arm: solvers.solve_ik(a, t), np.array(targets))
        without = timed(lambda t, a=plain: solvers.solve_ik(a, t), np.array(targets))
        ok = sum(solvers.solve_ik(arm, t).status == "ok" for t in targets) / len(targets)
        print(
            f"| {name} | floor + 3 boxes | {np.median(with_check):.1f} | {np.percentile(with_check, 99):.1f} "
            f"| {np.median(without):.1f} | {np.percentile(without, 99):.1f} | {ok:.1%} |"
        )


def check_table(n: int) -> None:
    print("| arm | world | pairs | in collision | check: median | p99 | fk alone: median | p99 |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for name in robots.names():
        arm = robots.load(name)
        assert arm.collision is not None
        rng = np.random.default_rng(sum(name.encode()))
        qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(n, arm.nq))
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
