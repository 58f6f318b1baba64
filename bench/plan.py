"""Planning benchmark: point-to-point plans and Cartesian lines, in-process.

* point to point: a Cartesian goal (IK seeded with the start) -> Ruckig -> samples at
  50 Hz -> safety gate -> actuator commands: ``planning.plan(robot, start, {"target": p})``.
* line: a 0.2 m straight line from a random start at rest, in a random direction the arm
  can follow (directions whose line leaves the reachable space or needs a branch flip are
  refused by the planner and drawn again; only planned lines are timed), ``path="line"``.
* peer in the same run: the bare Ruckig calculation of the same point-to-point segment,
  the floor under the whole plan.
* the world's cost: every plan is made twice, on the arm with its world (its floor and its
  own links: every sample and the joint moves between them checked, planning.clearance) and
  on the same arm without it; starts and goals are clear of collisions. A plan the world
  refuses (``collision``: the motion passes through the arm or the floor) is counted, not timed.
* around a box (``--around``, default 30 a arm): a clear start and goal and a box where the tool
  passes halfway along the straight move, which hits it: the plan goes round it (RRT-Connect,
  planning/sampling.py) and is timed; beside it, the same straight move planned without the box.

Run: ``.venv/bin/python bench/plan.py [--n 300]``. Prints a Markdown table of medians and
p99 [us] per arm.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import ruckig

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from armd import planning, robots
from armd.errors import CollisionError, PlanRejected
from armd.planning.clearance import check_clear
from armd.robots.collision import Obstacle


def _random_q(arm: robots.Robot, rng: np.random.Generator, n: int) -> np.ndarray:
    lim = arm.limits
    qs = rng.uniform(lim.lower, lim.upper, size=(20 * n, arm.nq))
    return qs[lim.contains_batch(qs, tol=0.0)][:n]


def _clear_q(arm: robots.Robot, rng: np.random.Generator, n: int) -> np.ndarray:
    world = arm.collision
    out: list[np.ndarray] = []
    while len(out) < n:
        for q in _random_q(arm, rng, n):
            if world is None or (world.first_contact(q) is None and float(arm.fk(q)[2]) >= (world.ground or -np.inf)):
                out.append(q)
    return np.array(out[:n])


def _plain(name: str) -> robots.Robot:
    arm = robots.load_folder(robots.CATALOGUE_DIR / name)
    arm.collision = None
    return arm


def _stats(us: list[float]) -> str:
    a = np.array(us)
    return f"{np.median(a):.0f} | {np.percentile(a, 99):.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300, help="plans per arm and kind")
    ap.add_argument("--around", type=int, default=30, help="plans round a box per arm")
    args = ap.parse_args()
    rng = np.random.default_rng(7)
    print(
        "| arm | p2p median us | p99 | p2p without the world median us | p99 | refused (collision) | "
        "bare Ruckig median us | p99 | line 0.2 m median us | p99 | without the world | p99 | lines planned |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rounds: list[tuple[str, list[float], list[float], int, int]] = []
    for name in robots.names():
        arm, plain = robots.load(name), _plain(name)
        starts = _clear_q(arm, rng, args.n)
        goals = _clear_q(arm, rng, args.n)
        targets = [arm.fk(q) for q in goals]
        planning.plan(arm, starts[0], {"target": targets[0].tolist()})  # warm-up (compiled code)
        p2p, p2p_plain, bare, line, line_plain = [], [], [], [], []
        refused = 0
        otg = ruckig.Ruckig(arm.nq, 0.02)
        for q0, q1, t in zip(starts, goals, targets, strict=True):
            t0 = time.perf_counter_ns()
            planning.plan(plain, q0, {"target": t.tolist()})
            without = (time.perf_counter_ns() - t0) / 1e3
            t0 = time.perf_counter_ns()
            try:
                planning.plan(arm, q0, {"target": t.tolist()})
            except CollisionError:
                refused += 1
            else:
                p2p.append((time.perf_counter_ns() - t0) / 1e3)
                p2p_plain.append(without)
            inp = ruckig.InputParameter(arm.nq)
            inp.current_position, inp.target_position = q0.tolist(), q1.tolist()
            inp.max_velocity = arm.limits.velocity.tolist()
            inp.max_acceleration = arm.limits.acceleration.tolist()
            inp.max_jerk = arm.limits.jerk.tolist()
            traj = ruckig.Trajectory(arm.nq)
            t0 = time.perf_counter_ns()
            otg.calculate(inp, traj)
            bare.append((time.perf_counter_ns() - t0) / 1e3)
        planned = tried = 0
        for q0 in starts[: max(10, args.n // 3)]:
            p0 = arm.fk(q0)
            for _ in range(30):  # a direction whose 0.2 m line the arm can follow, clear of its world
                d = rng.normal(size=3)
                p1 = p0 + 0.2 * d / np.linalg.norm(d)
                tried += 1
                t0 = time.perf_counter_ns()
                try:
                    planning.plan(arm, q0, {"target": p1.tolist()}, path="line")
                except (PlanRejected, CollisionError):
                    continue
                line.append((time.perf_counter_ns() - t0) / 1e3)
                t0 = time.perf_counter_ns()
                planning.plan(plain, q0, {"target": p1.tolist()}, path="line")
                line_plain.append((time.perf_counter_ns() - t0) / 1e3)
                planned += 1
                break
        rounds.append((name, *_around(arm, rng, args.around)))
        print(
            f"| {name} | {_stats(p2p)} | {_stats(p2p_plain)} | {refused}/{len(starts)} | {_stats(bare)} | "
            f"{_stats(line) if line else '- | -'} | {_stats(line_plain) if line_plain else '- | -'} | "
            f"{planned}/{tried} |"
        )
    print()
    print("| arm | round a box median us | p99 | the straight move without it, median us | p99 | planned | refused |")
    print("|---|---|---|---|---|---|---|")
    for name, took, straight, made, failed in rounds:
        print(f"| {name} | {_stats(took)} | {_stats(straight)} | {made} | {failed} |")


def _around(arm: robots.Robot, rng: np.random.Generator, n: int) -> tuple[list[float], list[float], int, int]:
    """Plans whose straight move hits a box where the tool passes halfway: timed round it."""
    took: list[float] = []
    straight: list[float] = []
    made = failed = 0
    world = arm.collision
    assert world is not None
    plain = _plain(arm.name)
    boxed = robots.load_folder(robots.CATALOGUE_DIR / arm.name)
    while made + failed < n:
        q0, q1 = _clear_q(arm, rng, 2)
        centre = arm.fk(0.5 * (q0 + q1))
        boxed.collision = world.with_obstacles([Obstacle("box", "box", (0.05, 0.05, 0.05), tuple(centre))])
        if boxed.collision.first_contact(q0) is not None or boxed.collision.first_contact(q1) is not None:
            continue
        t0 = time.perf_counter_ns()
        direct = planning.plan(plain, q0, q1)
        bare = (time.perf_counter_ns() - t0) / 1e3
        try:
            check_clear(boxed, direct.times, direct.position)
            continue  # (the straight move misses it: not this case)
        except CollisionError:
            pass
        t0 = time.perf_counter_ns()
        try:
            planning.plan(boxed, q0, q1)
        except CollisionError:
            failed += 1
            continue
        took.append((time.perf_counter_ns() - t0) / 1e3)
        straight.append(bare)
        made += 1
    return took, straight, made, failed


if __name__ == "__main__":
    main()
