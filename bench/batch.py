"""Batch IK benchmark: ``solve_ik_batch`` throughput with the arm's world checked and without it.

Per arm (every catalogue arm, ``robots.names()``, and the vendors' mycobot280 of
``examples/arms``, outside the closed-form family: the numerical batch), ``--n`` targets: the
tool points of random configurations within every limit and clear of the arm's world (itself,
its floor), each above the floor: reachable targets that every answer must reach ``ok``. Seeded
from the neutral pose, free pitch. Each batch of ``--n`` targets is one ``solve_ik_batch`` call,
timed with perf_counter (wall) and thread_time (this thread's CPU); the world on (the arm as
loaded) and off (``collisions=False``, the peer) take turns, batch after batch, so the
machine's slow stretches fall on both alike. ``--batches`` of each (``--numerical-batches``
for the numerical arm: about a second a batch).

Reported: targets per second (median of the batches, by wall clock, and its 1st percentile:
the p99 batch time's rate), targets per CPU second (median), and the statuses. Issue 36's bar:
>= 1,000,000 targets/s per core on the closed-form arms with the world on.

Then where the time goes, per target [us of CPU], median of the batches: the compiled closed
form alone (``solvers.analytic.solve_many`` over the batch), the world check of its answers
alone (``CompiledWorld.colliding``, one compiled call), and the whole batch with the world;
beside it, the same targets answered by a Python loop of ``solve_ik`` (what the numerical
arms' batch was), the world on and off.

Run: ``.venv/bin/python bench/batch.py [--n 10000] [--batches 15] [--numerical-batches 5]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from armd import robots, solvers
from armd.solvers.analytic import solve_many
from armd.solvers.arm import arm_state
from armd.solvers.ik import FREE_PITCHES
from armd.solvers.world import CompiledWorld, compiled

ROOT = Path(__file__).resolve().parent.parent
NUMERICAL = ROOT / "examples" / "arms" / "mycobot280"


def clear_targets(arm: robots.Robot, n: int, seed: int) -> np.ndarray:
    """Tool points of ``n`` random configurations within every limit, clear of ``arm``'s world,
    above its floor."""
    world = arm.collision
    assert world is not None
    rng = np.random.default_rng(seed)
    out: list[np.ndarray] = []
    while len(out) < n:
        qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(4 * n, arm.nq))
        qs = qs[arm.limits.contains_batch(qs, tol=0.0)]
        qs = qs[~world.colliding(qs)]
        for q in qs:
            p = arm.fk(q)
            if world.ground is None or p[2] >= world.ground:
                out.append(p)
    return np.array(out[:n])


def measure(arm: robots.Robot, targets: np.ndarray, batches: int) -> dict[str, object]:
    """Wall and CPU seconds of each batch, the world on and off in turn."""
    solvers.solve_ik_batch(arm, targets[:200])  # warm up (the atlas, the compiled world)
    solvers.solve_ik_batch(arm, targets[:200], collisions=False)
    wall: dict[bool, list[float]] = {True: [], False: []}
    cpu: dict[bool, list[float]] = {True: [], False: []}
    statuses: dict[bool, Counter[str]] = {True: Counter(), False: Counter()}
    for _ in range(batches):
        for on in (True, False):
            t, c = time.perf_counter(), time.thread_time()
            r = solvers.solve_ik_batch(arm, targets, collisions=on)
            cpu[on].append(time.thread_time() - c)
            wall[on].append(time.perf_counter() - t)
            statuses[on].update(r.status.tolist())
    return {"wall": wall, "cpu": cpu, "statuses": statuses}


def row(name: str, kind: str, n: int, got: dict[str, object]) -> str:
    wall, cpu, statuses = got["wall"], got["cpu"], got["statuses"]
    cells = []
    for on in (True, False):
        w = np.array(wall[on])  # type: ignore[index]
        c = np.array(cpu[on])  # type: ignore[index]
        cells += [f"{n / np.median(w):,.0f}", f"{n / np.percentile(w, 99):,.0f}", f"{n / np.median(c):,.0f}"]
    seen = statuses[True]  # type: ignore[index]
    total = sum(seen.values())
    ok = f"{seen['ok'] / total:.2%}"
    return f"| {name} | {kind} | {' | '.join(cells)} | {ok} |"


def cpu(fn: object, batches: int) -> float:
    """Median CPU seconds of ``fn()``."""
    out = []
    for _ in range(batches):
        c = time.thread_time()
        fn()  # type: ignore[operator]
        out.append(time.thread_time() - c)
    return float(np.median(out))


def pairs(world: CompiledWorld) -> str:
    """The pairs checked: compiled, and on coal (meshes) if any."""
    return f"{world.n_compiled}" + (f" + {len(world.coal_pairs)} on coal" if world.coal_pairs else "")


def loop(arm: robots.Robot, targets: np.ndarray) -> str:
    """A Python loop of ``solve_ik`` over the targets, the world on and off, [us] a target."""
    times = [cpu(lambda on=on: [solvers.solve_ik(arm, t, collisions=on) for t in targets], 3) for on in (True, False)]
    return " " + " | ".join(f"{1e6 * t / len(targets):.2f}" for t in times) + " |"


def stages(arm: robots.Robot, targets: np.ndarray, batches: int) -> str:
    """The closed form, the world check and the whole batch, [us] a target (the closed form:
    a closed-form arm's only)."""
    state = arm_state(arm)
    assert arm.collision is not None
    world = compiled(arm.collision)
    if state.packed_arm is None:
        whole = cpu(lambda: solvers.solve_ik_batch(arm, targets), batches)
        return f"| {arm.name} | {pairs(world)} | - | - | {1e6 * whole / len(targets):.2f} |"
    m, n = targets.shape[0], arm.nq
    refs = np.ascontiguousarray(np.broadcast_to(arm.neutral, (m, n)))
    prefs = np.ascontiguousarray(np.broadcast_to(FREE_PITCHES, (m, len(FREE_PITCHES))))
    q, reached = np.empty((m, n)), np.empty((m, 3))
    codes, ids, pitch, err = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64), np.empty(m), np.empty(m)

    def closed_form() -> None:
        solve_many(state.packed_arm, refs, targets, prefs, q, codes, pitch, ids, err, reached)

    closed_form()
    times = [
        cpu(closed_form, batches),
        cpu(lambda: world.colliding(q), batches),
        cpu(lambda: solvers.solve_ik_batch(arm, targets), batches),
    ]
    return f"| {arm.name} | {pairs(world)} | " + " | ".join(f"{1e6 * t / m:.2f}" for t in times) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="targets a batch (default 10,000)")
    ap.add_argument("--batches", type=int, default=15, help="batches of each kind, closed-form arms (default 15)")
    ap.add_argument("--numerical-batches", type=int, default=5, help="... the numerical arm (default 5)")
    args = ap.parse_args()
    print(
        "| arm | IK | world on: targets/s, median | p99 batch | per CPU s | world off: targets/s, median "
        "| p99 batch | per CPU s | ok (world on) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    arms = [(robots.load(name), args.batches) for name in robots.names()]
    arms.append((robots.load_folder(NUMERICAL), args.numerical_batches))
    targets = {arm.name: clear_targets(arm, args.n, sum(arm.name.encode())) for arm, _ in arms}
    for arm, batches in arms:
        kind = "closed form" if arm_state(arm).arrays is not None else "numerical"
        print(row(arm.name, kind, args.n, measure(arm, targets[arm.name], batches)), flush=True)
    print()
    print(
        "| arm | pairs checked (compiled) | closed form [us/target] | world check | whole batch, world on "
        "| loop of solve_ik, world on | world off |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for arm, batches in arms:
        print(stages(arm, targets[arm.name], batches) + loop(arm, targets[arm.name]), flush=True)


if __name__ == "__main__":
    main()
