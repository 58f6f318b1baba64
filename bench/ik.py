"""IK benchmark, TRAC-IK style: armd's solver against roboticstoolbox-python and ikpy.

For each arm: N random configurations inside every joint limit (box and coupled) -> FK
(``robot.fk``) -> target point -> position-only IK, from (a) the neutral seed
``robot.neutral`` and (b) a random in-limit seed. An answer counts as a success only when
its tool point, recomputed here with ``robot.fk``, is within ``--tol`` (1e-6 m) of the
target and it is inside every joint limit (``robot.limits.contains``, which includes
desk4's coupled limit). Times are ``time.perf_counter_ns`` around the solver call alone.
The solvers take turns on each case, 100 targets at a time in rotating order, so that the
machine's slow stretches (its speed wanders ~2x over minutes) fall on all of them alike.
Extra cases, from the neutral seed: reachable targets of configurations with joints on
their limits, and unreachable targets (1.1x and 1.5x an upper bound of the arm's reach, and
near the yaw axis), which a solver should give up on quickly. Each arm runs in a worker
process, so a solver that crashes the process costs one target, not the run.

Run from the repository root (see bench/README.md for the environment)::

    python bench/ik.py                      # n = 10,000 (ikpy capped at 500)
    python bench/ik.py --quick              # n = 300 (ikpy 100), a smoke run of about a minute
    python bench/ik.py --arms desk4 --solvers armd,rtb --n 2000 --out /tmp/ik.json

It prints Markdown tables to stdout (progress to stderr) and, with ``--out``, writes every
number and every problem found in armd's answers (each with a reproducer) as JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import gc
import json
import math
import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
if str(HERE.parent) not in sys.path:  # robots/ and solvers/ without an install
    sys.path.insert(1, str(HERE.parent))

import peers  # noqa: E402

from armd import robots  # noqa: E402

# Arms as their vendors publish them, loaded from their folders with no [geometry]: the SO-101
# with the vendor's rounded angles (a closed form found to 1.7e-6 m, refined on the exact model)
# and the six-joint myCobot 280 (outside the family: the numerical IK).
URDF_ARMS = [
    str(HERE.parent / "examples" / "arms" / name) for name in ("so101-vendor", "openmanipulator-x", "mycobot280")
]
DEFAULT_N = 10_000
QUICK_N = 300
# ikpy takes 10-60 ms a call (p99 up to a second on insomniac): 10,000 would take hours.
DEFAULT_CAPS = {"ikpy": 500}
QUICK_CAPS = {"ikpy": 100}  # --quick: a smoke run of about a minute
WARMUP = 10
NEAR, FAR = 1.1, 1.5  # unreachable targets: this many times reach_bound from the base origin
SLOW_FACTOR = 20.0  # an armd call this many times its median (and over 1 ms) is reported as slow
MAX_EXAMPLES = 5  # reproducers kept per kind of problem


# -- samples ------------------------------------------------------------------------------------


@dataclass
class Samples:
    """Everything random about one arm, drawn once so that every solver sees the same problems."""

    truth: np.ndarray  # (n, nq) the configurations the targets come from (clear of collisions)
    targets: np.ndarray  # (n, 3)
    random_seeds: np.ndarray  # (n, nq) in-limit seeds for case (b)
    reach: float  # upper bound of |tool point| [m]
    out_near: np.ndarray  # (m, 3) unreachable, just beyond reach
    out_far: np.ndarray  # (m, 3) unreachable, far
    out_axis: np.ndarray  # (m, 3) unreachable, above or below the base, 1 um to 1 cm off the z axis
    limit_truth: np.ndarray  # (m, nq) configurations with joints (and coupled limits) on their bounds
    limit_targets: np.ndarray  # (m, 3)


def draw(robot: Any, n: int, m: int, seed: int) -> Samples:
    rng = np.random.default_rng([seed, sum(robot.name.encode())])
    truth = peers.random_configs(robot, n, rng, clear=True)
    targets = np.array([robot.fk(q) for q in truth])
    random_seeds = peers.random_configs(robot, n, rng)
    reach = peers.reach_bound(robot)
    # Near: along the directions of reachable points (where the arm is), just past the bound.
    dirs = targets[:m] / np.linalg.norm(targets[:m], axis=1, keepdims=True)
    out_near = NEAR * reach * dirs
    out_far = FAR * reach * peers.unit_vectors(m, rng)
    limit_truth = peers.configs_at_limits(robot, m, rng, clear=True)
    limit_targets = np.array([robot.fk(q) for q in limit_truth])
    # Near the yaw axis, where the yaw angle is ill-defined: 1 um to 1 cm off it, above or below.
    off = 10.0 ** rng.uniform(-6, -2, size=m)
    angle = rng.uniform(-np.pi, np.pi, size=m)
    z = rng.choice([-1.0, 1.0], size=m) * rng.uniform(NEAR, FAR, size=m) * reach
    out_axis = np.column_stack([off * np.cos(angle), off * np.sin(angle), z])
    return Samples(truth, targets, random_seeds, reach, out_near, out_far, out_axis, limit_truth, limit_targets)


# -- running one case ------------------------------------------------------------------------------


@dataclass
class Case:
    arm: str
    solver: str
    case: str  # one of CASES
    reachable: bool
    n: int = 0
    times_ns: list[int] = field(default_factory=list)
    success: int = 0
    claimed: int = 0
    claimed_known: bool = False
    exceptions: int = 0
    off_target: int = 0  # an answer farther than tol from the target
    outside_limits: int = 0
    no_answer: int = 0
    statuses: dict[str, int] = field(default_factory=dict)
    worst_error: float = 0.0
    wall_s: float = 0.0
    crashes: int = 0  # targets whose call killed the worker process (counted as failures, not timed)
    crashed_indices: frozenset[int] = frozenset()
    transient_slow: int = 0  # armd outliers (> SLOW_FACTOR x median) that were fast when re-timed
    load_before: float = 0.0  # 1-minute load average when the case started

    def row(self) -> dict[str, Any]:
        t = np.array(self.times_ns, dtype=float) / 1e3
        out: dict[str, Any] = {
            "arm": self.arm,
            "solver": self.solver,
            "case": self.case,
            "reachable": self.reachable,
            "n": self.n,
            "success": self.success if self.reachable else None,
            "success_rate": (self.success / self.n if self.n else None) if self.reachable else None,
            "claimed": self.claimed if self.claimed_known else None,
            "exceptions": self.exceptions,
            "crashes": self.crashes,
            "off_target": self.off_target,
            "outside_limits": self.outside_limits,
            "no_answer": self.no_answer,
            "statuses": self.statuses or None,
            "median_us": float(np.median(t)) if len(t) else None,
            "p99_us": float(np.percentile(t, 99)) if len(t) else None,
            "mean_us": float(np.mean(t)) if len(t) else None,
            "max_us": float(np.max(t)) if len(t) else None,
            "wall_s": self.wall_s,
            "load_avg_1min": self.load_before,
        }
        if self.solver == "armd":
            out["transient_slow_calls"] = self.transient_slow
        if self.reachable:
            out["worst_error_m"] = self.worst_error
        return out


class Problems:
    """Wrong or suspicious answers from armd's solver, each kind with a few reproducers."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self.examples: dict[str, list[dict[str, Any]]] = {}

    def add(self, kind: str, example: dict[str, Any]) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + 1
        ex = self.examples.setdefault(kind, [])
        if len(ex) < MAX_EXAMPLES:
            ex.append(example)

    def merge(self, other: dict[str, Any]) -> None:
        """Add the problems of another run (the ``as_json`` form)."""
        for kind, p in other.items():
            self.counts[kind] = self.counts.get(kind, 0) + p["count"]
            ex = self.examples.setdefault(kind, [])
            ex.extend(p["examples"][: MAX_EXAMPLES - len(ex)])

    def as_json(self) -> dict[str, Any]:
        return {k: {"count": self.counts[k], "examples": self.examples[k]} for k in sorted(self.counts)}


def reproducer(arm: str, target: np.ndarray, seed: np.ndarray | None) -> str:
    seed_s = "None" if seed is None else f"np.array({[float(x) for x in seed]!r})"
    return (
        "import numpy as np, robots\nfrom solvers import solve_ik\n"
        f"arm = robots.load({arm!r}) if {arm!r} in robots.names() else robots.load_folder({arm!r})\n"
        f"target = np.array({[float(x) for x in target]!r})\n"
        f"r = solve_ik(arm, target, seed={seed_s})\n"
        "print(r.status, r.position_error, np.linalg.norm(arm.fk(r.q) - target), arm.limits.contains(r.q), r.q)\n"
    )


class CaseRun:
    """One solver on one case, run in chunks (:data:`CHUNK`) so that solvers can take turns.

    Every target is solved once from its seed, timing the solver call alone, and each answer
    is checked. ``crashed``: indices whose call killed an earlier worker; they count as
    failures, uncalled.
    """

    def __init__(
        self,
        adapter: peers.Adapter,
        robot: Any,
        case: Case,
        targets: np.ndarray,
        seeds: np.ndarray,
        truth: np.ndarray | None,
        tol: float,
        problems: Problems | None,
        crumb: Crumb | None = None,
        crashed: set[int] | frozenset[int] = frozenset(),
    ) -> None:
        self.adapter, self.robot, self.case = adapter, robot, case
        self.targets, self.seeds, self.truth, self.tol, self.problems = targets, seeds, truth, tol, problems
        self.crumb = crumb or Crumb(None)
        self.crashed = frozenset(crashed)
        case.crashed_indices = self.crashed
        self.prepared = [adapter.prepare(t) for t in targets]
        for i in [i for i in range(len(targets)) if i not in self.crashed][:WARMUP]:  # fill caches, compile
            self.crumb.at(case.solver, case.case, i)
            with contextlib.suppress(Exception):
                adapter.call(self.prepared[i], seeds[i])
        case.n = len(targets)
        case.load_before = os.getloadavg()[0]
        case.claimed_known = adapter.name in ("armd", "rtb")

    def run(self, lo: int, hi: int) -> None:
        """Targets ``lo`` to ``hi`` (clipped to this case's count)."""
        case, adapter, crumb, problems = self.case, self.adapter, self.crumb, self.problems
        wall = time.perf_counter()
        clock = time.perf_counter_ns
        for i in range(lo, min(hi, case.n)):
            if i in self.crashed:
                case.crashes += 1
                case.no_answer += 1
                continue
            seed = self.seeds[i]
            err_text = trace = None
            crumb.at(case.solver, case.case, i)
            t0 = clock()
            try:
                raw = adapter.call(self.prepared[i], seed)
            except Exception as e:  # counted, never fatal: a solver that raises fails that target
                t1 = clock()
                raw = None
                err_text = f"{type(e).__name__}: {e}"
                trace = traceback.format_exc(limit=-3)
            else:
                t1 = clock()
            case.times_ns.append(t1 - t0)
            if raw is None:
                case.exceptions += 1
                case.no_answer += 1
                if problems is not None:
                    problems.add(
                        "exception",
                        {
                            "arm": case.arm,
                            "case": case.case,
                            "error": err_text,
                            "trace": trace,
                            "reproducer": reproducer(case.arm, self.targets[i], seed),
                        },
                    )
                continue
            check(
                adapter,
                self.robot,
                case,
                raw,
                self.targets[i],
                seed,
                None if self.truth is None else self.truth[i],
                self.tol,
                problems,
                (t1 - t0),
            )
        case.wall_s += time.perf_counter() - wall

    def finish(self) -> Case:
        if self.problems is not None and self.case.times_ns:
            slow_report(self.adapter, self.case, self.prepared, self.targets, self.seeds, self.problems, self.crumb)
        return self.case


def check(
    adapter: peers.Adapter,
    robot: Any,
    case: Case,
    raw: Any,
    target: np.ndarray,
    seed: np.ndarray,
    truth: np.ndarray | None,
    tol: float,
    problems: Problems | None,
    ns: int,
) -> None:
    try:
        ans = adapter.answer(raw, seed)
    except Exception as e:
        case.no_answer += 1
        if problems is not None:
            problems.add(
                "malformed answer",
                {
                    "arm": case.arm,
                    "case": case.case,
                    "error": f"{type(e).__name__}: {e}",
                    "reproducer": reproducer(case.arm, target, seed),
                },
            )
        return
    if ans.claimed:
        case.claimed += 1
    if ans.status is not None:
        case.statuses[ans.status] = case.statuses.get(ans.status, 0) + 1
    q = ans.q
    if q is None or q.shape != (robot.nq,) or not np.all(np.isfinite(q)):
        case.no_answer += 1
        if problems is not None:
            problems.add(
                "no joint vector",
                {
                    "arm": case.arm,
                    "case": case.case,
                    "q": None if q is None else repr(q),
                    "reproducer": reproducer(case.arm, target, seed),
                },
            )
        return
    err = float(np.linalg.norm(robot.fk(q) - target))
    inside = robot.limits.contains(q)
    on_target = err <= tol
    if not inside:
        case.outside_limits += 1
    if not on_target:
        case.off_target += 1
    if case.reachable:
        case.worst_error = max(case.worst_error, err)
        if on_target and inside:
            case.success += 1
    if problems is None:
        return
    ex = {
        "arm": case.arm,
        "case": case.case,
        "status": ans.status,
        "actual_error_m": err,
        "reported_error_m": ans.reported_error,
        "inside_limits": inside,
        "q": q.tolist(),
        "time_us": ns / 1e3,
        "reproducer": reproducer(case.arm, target, seed),
    }
    if truth is not None:
        ex["a_solution"] = truth.tolist()
    if not inside:
        problems.add("answer outside joint limits", ex)
    if ans.reported_error is not None and not math.isclose(ans.reported_error, err, rel_tol=1e-6, abs_tol=1e-9):
        problems.add("position_error differs from |fk(q) - target|", ex)
    if case.reachable:
        if ans.status == "ok" and not on_target:
            problems.add("status ok but off target (reachable target)", ex)
        elif ans.status != "ok" and on_target and inside:
            problems.add(f"status {ans.status!r} but the answer is on target", ex)
        elif ans.status != "ok":
            problems.add(f"reachable target answered {ans.status!r}", ex)
    else:
        # (armd answers a target below the arm's floor ``collision``, naming the tool and the
        # ground: it is out of reach because of the world; the peers know no floor)
        world = robot.collision
        under = world is not None and world.ground is not None and float(target[2]) < world.ground
        if ans.status != "unreachable" and not (ans.status == "collision" and under):
            problems.add(f"unreachable target answered {ans.status!r}", ex)


def slow_report(
    adapter: peers.Adapter,
    case: Case,
    prepared: list[Any],
    targets: np.ndarray,
    seeds: np.ndarray,
    problems: Problems,
    crumb: Crumb,
) -> None:
    """Report armd calls far slower than the median, if they stay slow when timed again.

    On a shared 2-core machine a call now and then takes milliseconds because the process
    was descheduled; re-timing each outlier separates those from targets that are slow.
    """
    t = np.array(case.times_ns)
    med = float(np.median(t))
    limit = max(SLOW_FACTOR * med, 1e6)
    called = [i for i in range(case.n) if i not in case.crashed_indices]  # times_ns skips crashed ones
    slow = np.flatnonzero(t > limit)
    for k in slow[np.argsort(-t[slow])]:
        i = called[k]
        crumb.at(case.solver, case.case, i)
        again = []
        for _ in range(3):
            t0 = time.perf_counter_ns()
            with contextlib.suppress(Exception):
                adapter.call(prepared[i], seeds[i])
            again.append(time.perf_counter_ns() - t0)
        if min(again) > limit:
            problems.add(
                "slow call (slow again when re-timed)",
                {
                    "arm": case.arm,
                    "case": case.case,
                    "time_us": float(t[k]) / 1e3,
                    "retimed_min_us": min(again) / 1e3,
                    "median_us": med / 1e3,
                    "reproducer": reproducer(case.arm, targets[i], seeds[i]),
                },
            )
        else:
            case.transient_slow += 1


def run_batch(robot: Any, batch: Any, s: Samples, tol: float, problems: Problems) -> dict[str, Any]:
    """``solve_ik_batch(robot, targets)`` on all reachable targets at once: targets per second."""
    out: dict[str, Any] = {"arm": robot.name, "n": len(s.targets)}
    try:
        batch(robot, s.targets[:WARMUP])
        gc.collect()
        t0 = time.perf_counter_ns()
        res = batch(robot, s.targets)
        t1 = time.perf_counter_ns()
    except Exception as e:
        problems.add(
            "solve_ik_batch exception",
            {"arm": robot.name, "error": f"{type(e).__name__}: {e}", "trace": traceback.format_exc(limit=-3)},
        )
        out["error"] = f"{type(e).__name__}: {e}"
        return out
    seconds = (t1 - t0) / 1e9
    out["seconds"] = seconds
    out["targets_per_s"] = len(s.targets) / seconds if seconds > 0 else None
    try:
        q = np.asarray(res.q, dtype=float)
        status = np.asarray(res.status)
        reported = np.asarray(res.position_error, dtype=float)
        err = np.linalg.norm(np.array([robot.fk(x) for x in q]) - s.targets, axis=1)
        inside = robot.limits.contains_batch(q)
        ok = (err <= tol) & inside
        out["success"] = int(ok.sum())
        out["success_rate"] = float(ok.mean())
        out["statuses"] = {str(k): int(v) for k, v in zip(*np.unique(status, return_counts=True), strict=True)}
        bad_ok = np.flatnonzero((status == "ok") & ~ok)
        for i in bad_ok[:MAX_EXAMPLES]:
            problems.add(
                "batch: status ok but wrong",
                {
                    "arm": robot.name,
                    "target": s.targets[i].tolist(),
                    "q": q[i].tolist(),
                    "actual_error_m": float(err[i]),
                    "inside_limits": bool(inside[i]),
                    "reproducer": (
                        f"import numpy as np, robots, solvers\narm = robots.load({robot.name!r})\n"
                        f"t = np.array([{[float(x) for x in s.targets[i]]!r}])\n"
                        "r = solvers.solve_ik_batch(arm, t)\nprint(r.status, r.q, r.position_error)\n"
                    ),
                },
            )
        mism = np.flatnonzero(~np.isclose(reported, err, rtol=1e-6, atol=1e-9))
        if len(mism):
            problems.add(
                "batch: position_error differs from |fk(q) - target|",
                {
                    "arm": robot.name,
                    "count": len(mism),
                    "first": int(mism[0]),
                    "reported": float(reported[mism[0]]),
                    "actual": float(err[mism[0]]),
                },
            )
    except Exception as e:
        problems.add("solve_ik_batch malformed result", {"arm": robot.name, "error": f"{type(e).__name__}: {e}"})
        out["error"] = f"malformed result: {type(e).__name__}: {e}"
    return out


# -- output ---------------------------------------------------------------------------------------


def fmt_us(x: float | None) -> str:
    if x is None:
        return "-"
    return f"{x:,.0f}" if x >= 100 else f"{x:.1f}"


def markdown(results: dict[str, Any]) -> str:
    rows = results["results"]
    meta = results["meta"]
    lines = [
        f"IK benchmark: position-only, success = |robot.fk(q) - target| <= {meta['tol']:g} m and q inside "
        f"every joint limit. Times: perf_counter_ns around one solver call, microseconds.",
        "",
    ]
    caps = {k: v for k, v in meta["n_per_solver"].items() if v < meta["n"]}
    if caps:
        lines.append(
            "Samples: n = {:,} per arm and seed; capped: {}.".format(
                meta["n"], ", ".join(f"{k} at n = {v:,}" for k, v in caps.items())
            )
        )
        lines.append("")
    lines += [
        "### Reachable targets",
        "",
        "| arm | solver | n | success (neutral seed) | median | p99 | success (random seed) | median | p99 |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    by = {(r["arm"], r["solver"], r["case"]): r for r in rows}
    pairs = sorted({(r["arm"], r["solver"]) for r in rows}, key=lambda p: (p[0], meta["solvers"].index(p[1])))
    for arm, solver in pairs:
        a, b = by.get((arm, solver, "neutral")), by.get((arm, solver, "random"))
        if a is None and b is None:
            continue
        first = a if a is not None else b
        assert first is not None
        cells = [arm, solver, f"{first['n']:,}"]
        for r in (a, b):
            if r is None:
                cells += ["-", "-", "-"]
            else:
                cells += [f"{100 * r['success_rate']:.2f}%", fmt_us(r["median_us"]), fmt_us(r["p99_us"])]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "### Unreachable targets (neutral seed)",
        "",
        f"near: {NEAR}x an upper bound of the reach, along directions of reachable points; far: {FAR}x, "
        f"random directions; axis: {NEAR}-{FAR}x straight above or below the base, 1 um to 1 cm off the "
        "yaw axis.",
        "",
        "| arm | solver | n | median (near) | p99 (near) | median (far) | p99 (far) | median (axis) "
        "| p99 (axis) | said unreachable |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for arm, solver in pairs:
        cases = [by.get((arm, solver, c)) for c in ("out_near", "out_far", "out_axis")]
        got = [r for r in cases if r is not None]
        if not got:
            continue
        tot = sum(r["n"] for r in got)
        said = "-"
        if solver == "armd":
            said = f"{sum((r['statuses'] or {}).get('unreachable', 0) for r in got)}/{tot}"
        elif solver == "rtb":
            said = f"{tot - sum(r['claimed'] or 0 for r in got)}/{tot}"
        crashes = sum(r.get("crashes", 0) for r in got)
        if crashes:
            said += f" ({crashes} crashed)"
        cells = [arm, solver, f"{got[0]['n']:,}"]
        for r in cases:
            cells += ["-", "-"] if r is None else [fmt_us(r["median_us"]), fmt_us(r["p99_us"])]
        cells.append(said)
        lines.append("| " + " | ".join(cells) + " |")
    at = [by[(arm, solver, "at_limits")] for arm, solver in pairs if (arm, solver, "at_limits") in by]
    if at:
        lines += [
            "",
            "### Reachable targets from configurations on their joint limits (extra; neutral seed)",
            "",
            "Each joint on a bound with probability 1/2, each coupled limit active with probability 1/2.",
            "",
            "| arm | solver | n | success | median | p99 |",
            "|---|---|---:|---:|---:|---:|",
        ]
        for r in at:
            lines.append(
                f"| {r['arm']} | {r['solver']} | {r['n']:,} | {100 * r['success_rate']:.2f}% | "
                f"{fmt_us(r['median_us'])} | {fmt_us(r['p99_us'])} |"
            )
    if results.get("batch"):
        lines += [
            "",
            "### armd solve_ik_batch (all reachable targets in one call)",
            "",
            "| arm | n | targets/s | success | statuses |",
            "|---|---:|---:|---:|---|",
        ]
        for b in results["batch"]:
            if "error" in b and "targets_per_s" not in b:
                lines.append(f"| {b['arm']} | {b['n']:,} | error: {b['error']} | - | - |")
                continue
            tps = b.get("targets_per_s")
            rate = b.get("success_rate")
            lines.append(
                f"| {b['arm']} | {b['n']:,} | {tps:,.0f} | "
                f"{'-' if rate is None else f'{100 * rate:.2f}%'} | {b.get('statuses', '-')} |"
            )
    lines += [
        "",
        "### Models and FK agreement",
        "",
        "| arm | solver | model | max FK difference [m] |",
        "|---|---|---|---:|",
    ]
    for arm, info in results["arms"].items():
        for solver, p in info["solvers"].items():
            if "unavailable" in p:
                lines.append(f"| {arm} | {solver} | not run: {p['unavailable']} | - |")
            else:
                fe = p.get("fk_error")
                lines.append(f"| {arm} | {solver} | {p['source']} | {'-' if fe is None else f'{fe:.1e}'} |")
    fails = [r for r in rows if r["reachable"] and r["n"] and r["success"] < r["n"]]
    if fails:
        lines += [
            "",
            "### Why reachable targets failed",
            "",
            "| arm | solver | case | failures | off target | outside limits | exceptions | crashes | claimed ok |",
            "|---|---|---|---:|---:|---:|---:|---:|---:|",
        ]
        for r in fails:
            lines.append(
                f"| {r['arm']} | {r['solver']} | {r['case']} | {r['n'] - r['success']} | {r['off_target']} | "
                f"{r['outside_limits']} | {r['exceptions']} | {r.get('crashes', 0)} | "
                f"{'-' if r['claimed'] is None else r['claimed']} |"
            )
    for arm, info in results["arms"].items():
        if info.get("worker_error"):
            lines += ["", f"**{arm}: the run is incomplete**: {info['worker_error'][:500]}"]
    for c in results.get("peer_crashes", []):
        lines += [
            "",
            f"**{c['solver']} crashed the process** on {c['arm']} {c['case']} target {c['index']} ({c['why']}).",
        ]
    probs = results.get("problems") or {}
    if probs:
        lines += ["", "### Problems in armd's answers", ""]
        for kind, p in probs.items():
            lines.append(f"- {kind}: {p['count']}")
        for kind, p in probs.items():
            ex = p["examples"][0]
            detail = {
                k: ex[k]
                for k in (
                    "arm",
                    "case",
                    "status",
                    "actual_error_m",
                    "reported_error_m",
                    "inside_limits",
                    "time_us",
                    "error",
                    "why",
                )
                if k in ex
            }
            lines += ["", f"{kind}, e.g. {detail}:"]
            if "reproducer" in ex:
                lines += ["```python", ex["reproducer"].rstrip(), "```"]
        lines.append("")
        lines.append("(every example, with its q and a known solution, is in the JSON file: --out)")
    loads = [r["load_avg_1min"] for r in rows]
    g = meta.get("git") or {}
    changed = g.get("uncommitted_in_solvers_or_robots") or []
    dirty = f" with uncommitted changes in {len(changed)} files of solvers/ or robots/" if changed else ""
    lines += [
        "",
        "Environment: " + ", ".join(f"{k} {v}" for k, v in meta["versions"].items()),
        f"armd at commit {g.get('commit')}" + dirty + ".",
        f"Run took {meta['seconds']:.0f} s.",
    ]
    if loads and max(loads) > 1.5:
        lines.append(
            f"Warning: the 1-minute load average reached {max(loads):.1f} during the run (this benchmark "
            "alone makes it ~1): other processes shared the cores, so times are noisy."
        )
    return "\n".join(lines)


# -- main -------------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--n", type=int, default=None, help=f"random configurations per arm (default {DEFAULT_N:,})")
    ap.add_argument(
        "--quick",
        action="store_true",
        help=f"smoke run: n = {QUICK_N} unless --n is given, ikpy capped at {QUICK_CAPS['ikpy']}",
    )
    ap.add_argument("--arms", default=None, help="comma-separated arms (default: the whole catalogue)")
    ap.add_argument("--solvers", default="armd,rtb,ikpy", help="comma-separated, from: armd, rtb, ikpy")
    ap.add_argument("--out", default=None, help="write every result as JSON to this file")
    ap.add_argument("--tol", type=float, default=1e-6, help="position tolerance for a success [m] (default 1e-6)")
    ap.add_argument(
        "--unreachable",
        type=int,
        default=None,
        help="targets per extra case (at_limits, out_near, out_far, out_axis) and arm (default n/40, "
        "at least 50; for a capped solver at most max(50, its n/10))",
    )
    ap.add_argument(
        "--cap",
        action="append",
        default=[],
        metavar="SOLVER=N",
        help="at most N samples for SOLVER (default: ikpy=500); N = 0 removes the cap",
    )
    ap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ap.add_argument("--no-batch", action="store_true", help="skip solvers.solve_ik_batch")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)  # internal: run one arm, see worker()
    args = ap.parse_args(argv)
    if args.n is None:
        args.n = QUICK_N if args.quick else DEFAULT_N
    if args.n < 1:
        ap.error("--n must be at least 1")
    args.arms = args.arms.split(",") if args.arms else robots.names() + URDF_ARMS
    for a in args.arms:
        if a not in robots.names() and not (Path(a) / "robot.toml").is_file():
            ap.error(f"unknown arm {a!r}; arms: {', '.join(robots.names())}, or an arm's folder")
    args.solvers = [s for s in args.solvers.split(",") if s]
    for s in args.solvers:
        if s not in peers.SOLVERS:
            ap.error(f"unknown solver {s!r}; solvers: {', '.join(peers.SOLVERS)}")
    caps = dict(QUICK_CAPS if args.quick else DEFAULT_CAPS)
    for c in args.cap:
        name, _, value = c.partition("=")
        if name not in peers.SOLVERS or not value.isdigit():
            ap.error(f"--cap wants SOLVER=N with SOLVER one of {', '.join(peers.SOLVERS)}, got {c!r}")
        caps[name] = int(value)
    args.n_per_solver = {s: (min(args.n, caps[s]) if caps.get(s) else args.n) for s in args.solvers}
    if args.unreachable is None:
        args.unreachable = max(50, args.n // 40)
    return args


def load_arm(name: str) -> Any:
    """A catalogue arm by name, or an arm's folder by path."""
    return robots.load(name) if name in robots.names() else robots.load_folder(Path(name).resolve())


def git_state() -> dict[str, Any]:
    """The commit measured and whether solvers/ or robots/ differ from it (read-only git calls)."""
    import subprocess

    def git(*a: str) -> str:
        try:
            return subprocess.run(
                ["git", "-C", str(HERE.parent), *a], capture_output=True, text=True, timeout=10
            ).stdout.strip()
        except Exception:
            return ""

    changed = git("status", "--porcelain", "--", "solvers", "robots")
    return {
        "commit": git("rev-parse", "--short", "HEAD") or None,
        "uncommitted_in_solvers_or_robots": changed.splitlines() if changed else [],
    }


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


CASES = ("neutral", "random", "at_limits", "out_near", "out_far", "out_axis")
CHUNK = 100  # targets per turn when the solvers take turns on a case
MAX_RESTARTS = 20  # worker crashes tolerated per arm (each skips the target that crashed)


def case_inputs(
    robot: Any, s: Samples, args: argparse.Namespace, solver: str, case: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, bool]:
    """(targets, seeds, known solutions or None, reachable) of one case for one solver."""
    n = args.n_per_solver[solver]
    m = min(args.unreachable, n if n == args.n else max(50, n // 10))
    neutral = np.tile(robot.neutral, (max(n, m), 1))
    if case == "neutral":
        return s.targets[:n], neutral[:n], s.truth[:n], True
    if case == "random":
        return s.targets[:n], s.random_seeds[:n], s.truth[:n], True
    if case == "out_near":
        return s.out_near[:m], neutral[:m], None, False
    if case == "out_far":
        return s.out_far[:m], neutral[:m], None, False
    if case == "out_axis":
        return s.out_axis[:m], neutral[:m], None, False
    if case == "at_limits":
        return s.limit_targets[:m], neutral[:m], s.limit_truth[:m], True
    raise ValueError(case)


class Crumb:
    """Where the worker is: written before every solver call, read by the parent if the worker dies."""

    def __init__(self, path: Path | None) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC) if path else None

    def at(self, solver: str, case: str, index: int) -> None:
        if self.fd is not None:
            os.pwrite(self.fd, f"{solver} {case} {index}".ljust(64).encode(), 0)


def worker(args: argparse.Namespace) -> int:
    """Run one arm (``--arms``) in this process, appending a JSON line per finished piece to the work dir.

    The parent runs each arm in a worker so that a solver that kills the process (a segfault
    in compiled code) costs one target, not the whole run: the parent reads the crumb, records
    the crash and starts the worker again, skipping what is done and the target that crashed.
    """
    import faulthandler

    work = Path(args.worker)
    skip = json.loads((work / "skip.json").read_text())
    done = {tuple(d) for d in skip["done"]}
    crashed: dict[tuple[str, str], set[int]] = {}
    for solver, case, index in skip["crashed"]:
        crashed.setdefault((solver, case), set()).add(int(index))
    fault = (work / "fault.txt").open("w")
    faulthandler.enable(file=fault)
    crumb = Crumb(work / "crumb")
    records = (work / "records.jsonl").open("a")

    def record(kind: str, **data: Any) -> None:
        records.write(json.dumps({"type": kind, **data}, default=float) + "\n")
        records.flush()

    arm_name = args.arms[0]
    robot = load_arm(arm_name)
    s = draw(robot, args.n, args.unreachable, args.seed)
    if not skip["done"] and not skip["crashed"]:
        log(f"{arm_name}: {robot.nq} joints, reach bound {s.reach:.4f} m")
    record("arm", info={"nq": robot.nq, "reach_bound_m": s.reach})
    adapters: dict[str, peers.Adapter] = {}
    for solver in args.solvers:
        if all((solver, c) in done for c in CASES):
            continue
        try:
            adapters[solver] = peers.SOLVERS[solver](robot, args.tol)
        except peers.Unavailable as e:
            record("solver", solver=solver, info={"unavailable": str(e)})
            log(f"  {solver}: not run: {e}")
            continue
        record("solver", solver=solver, info={"source": adapters[solver].source, "fk_error": adapters[solver].fk_error})
    for case_name in CASES:
        runs: list[CaseRun] = []
        for solver, adapter in adapters.items():
            if (solver, case_name) in done:
                continue
            targets, seeds, truth, reachable = case_inputs(robot, s, args, solver, case_name)
            problems = Problems() if solver == "armd" else None
            runs.append(
                CaseRun(
                    adapter,
                    robot,
                    Case(arm_name, solver, case_name, reachable),
                    targets,
                    seeds,
                    truth,
                    args.tol,
                    problems,
                    crumb,
                    crashed.get((solver, case_name), set()),
                )
            )
        # the solvers take turns, a chunk each (the order rotating), so that the machine's slow
        # stretches fall on every solver alike and the ratios between them are fair
        gc.collect()
        longest = max((r.case.n for r in runs), default=0)
        for turn, lo in enumerate(range(0, longest, CHUNK)):
            for k in range(len(runs)):
                runs[(turn + k) % len(runs)].run(lo, lo + CHUNK)
        for r in runs:
            case = r.finish()
            row = case.row()
            record(
                "case",
                solver=case.solver,
                case=case_name,
                row=row,
                problems=r.problems.as_json() if r.problems is not None else {},
            )
            rate = f"{100 * row['success_rate']:.2f}% ok, " if case.reachable else ""
            log(
                f"  {case.solver:5s} {case_name:9s} n={row['n']:<6} {rate}median {fmt_us(row['median_us'])} us, "
                f"p99 {fmt_us(row['p99_us'])} us ({row['wall_s']:.1f} s)"
            )
    if (
        "armd" in args.solvers
        and not args.no_batch
        and ("armd", "batch") not in done
        and ("armd", "batch") not in crashed
    ):
        batch = peers.armd_batch(robot)
        if batch is not None:
            problems = Problems()
            crumb.at("armd", "batch", -1)
            b = run_batch(robot, batch, s, args.tol, problems)
            record("batch", row=b, problems=problems.as_json())
            log(f"  armd  batch     n={b['n']} {b.get('targets_per_s') or 0:,.0f} targets/s")
    return 0


def run_arm(arm_name: str, args: argparse.Namespace, results: dict[str, Any], problems: Problems) -> None:
    """Run one arm in worker processes until it is done, recording any worker that dies."""
    import shutil
    import subprocess
    import tempfile

    work = Path(tempfile.mkdtemp(prefix="armd-bench-"))
    done: list[list[Any]] = []
    crashed: list[list[Any]] = []
    info: dict[str, Any] = {"solvers": {}}
    results["arms"][arm_name] = info
    rows: dict[tuple[str, str], dict[str, Any]] = {}
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--worker",
        str(work),
        "--arms",
        arm_name,
        "--n",
        str(args.n),
        "--solvers",
        ",".join(args.solvers),
        "--tol",
        repr(args.tol),
        "--unreachable",
        str(args.unreachable),
        "--seed",
        str(args.seed),
    ]
    cmd += [f"--cap={k}={v}" for k, v in args.n_per_solver.items()]
    if args.no_batch:
        cmd.append("--no-batch")
    try:
        for _ in range(MAX_RESTARTS + 1):
            (work / "skip.json").write_text(json.dumps({"done": done, "crashed": crashed}))
            (work / "records.jsonl").write_text("")
            (work / "crumb").write_text("")
            rc = subprocess.run(cmd).returncode
            for line in (work / "records.jsonl").read_text().splitlines():
                rec = json.loads(line)
                if rec["type"] == "arm":
                    info.update(rec["info"])
                elif rec["type"] == "solver":
                    info["solvers"][rec["solver"]] = rec["info"]
                elif rec["type"] == "case":
                    rows[(rec["solver"], rec["case"])] = rec["row"]
                    problems.merge(rec["problems"])
                    done.append([rec["solver"], rec["case"]])
                elif rec["type"] == "batch":
                    results["batch"].append(rec["row"])
                    problems.merge(rec["problems"])
                    done.append(["armd", "batch"])
            if rc == 0:
                break
            where = (work / "crumb").read_text().split()
            fault = (work / "fault.txt").read_text() if (work / "fault.txt").exists() else ""
            fault = "\n".join(ln for ln in fault.splitlines() if not ln.startswith("Extension modules"))
            why = f"signal {-rc}" if rc < 0 else f"exit code {rc}"
            if len(where) != 3:
                log(f"  worker for {arm_name} died ({why}) outside any solver call; giving up on this arm")
                info["worker_error"] = f"died ({why}) outside a solver call: {fault[-2000:]}"
                break
            solver, case, index = where[0], where[1], int(where[2])
            crashed.append([solver, case, index])
            log(f"  {solver} crashed the process ({why}) on {case} target {index}: skipping it")
            example: dict[str, Any] = {
                "arm": arm_name,
                "solver": solver,
                "case": case,
                "index": index,
                "why": why,
                "python_trace": fault[-3000:],
            }
            if case == "batch":
                done.append(["armd", "batch"])
                results["batch"].append({"arm": arm_name, "n": args.n, "error": f"crashed the process ({why})"})
            else:
                robot = load_arm(arm_name)
                s = draw(robot, args.n, args.unreachable, args.seed)
                targets, seeds, _, _ = case_inputs(robot, s, args, solver, case)
                example["reproducer"] = reproducer(arm_name, targets[index], seeds[index])
                if solver != "armd":
                    example["reproducer"] = f"# {solver} adapter (bench/peers.py) on this target and seed\n" + example[
                        "reproducer"
                    ].replace("solve_ik(", f"<{solver}>(")
            if solver == "armd":
                problems.add(f"process crashed ({why})", example)
            else:
                results.setdefault("peer_crashes", []).append(example)
        else:
            info["worker_error"] = f"gave up after {MAX_RESTARTS} crashes"
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for solver in args.solvers:
        for case in CASES:
            if (solver, case) in rows:
                results["results"].append(rows[(solver, case)])


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.worker:
        return worker(args)
    started = time.perf_counter()
    results: dict[str, Any] = {
        "meta": {
            "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
            "n": args.n,
            "n_per_solver": args.n_per_solver,
            "unreachable_per_kind": args.unreachable,
            "tol": args.tol,
            "seed": args.seed,
            "solvers": args.solvers,
            "arms": args.arms,
            "rtb_tol": peers.rtb_tolerance(args.tol),
            "ikpy_tol": peers.Ikpy.IKPY_TOL,
            "versions": peers.versions(),
            "git": git_state(),
            "env": {
                k: os.environ[k]
                for k in ("OPENBLAS_CORETYPE", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
                if k in os.environ
            },
        },
        "arms": {},
        "results": [],
        "batch": [],
    }
    problems = Problems()
    for arm_name in args.arms:
        run_arm(arm_name, args, results, problems)
    results["problems"] = problems.as_json()
    results["meta"]["seconds"] = time.perf_counter() - started
    print(markdown(results))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results, indent=1, default=float))
        log(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
