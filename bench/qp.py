"""Which QP for the IK's numerical stage? armd's compiled active set vs DAQP vs OSQP vs PlaCo.

The task is the refinement armd runs when the closed form is not exact on the URDF: from
a start near a solution (a random in-limit configuration's joints, each moved by up to
``--spread`` rad, projected into the limits), bring the tool point onto the target within
1e-9 m, never leaving the joint limits.

* ``armd``: armd's refinement (``solvers.lm.refine_chain``): Levenberg-Marquardt on the URDF's
  compiled chain, every step a QP with hard box and coupled limits solved by armd's own
  compiled active set (``solvers/activeset.py``); one native call a refinement.
* ``daqp``: the same iteration in Python on Pinocchio, each step's QP solved by DAQP (a dual
  active-set solver for small dense QPs): armd's numerical stage until issue 16
  (``bench/daqp_lm.py``).
* ``osqp``: that Python iteration with each step's QP solved by OSQP through qpsolvers
  (eps 1e-9; OSQP is an ADMM first-order solver).
* ``placo``: PlaCo's KinematicsSolver: a position task on the tool frame, joint limits on,
  ``solve(True)`` repeated until the error is below 1e-9 m or 200 steps.
  PlaCo parses the URDF without mimic joints, so the desk4 (linkage as mimic joints) is
  left out for it.

Run: ``python bench/qp.py`` in the bench environment (bench/README.md; ``--n`` starts per
arm). Prints a Markdown table: success rate at 1e-9 m, median and p99 time per refinement
[us], median iterations, and each method's median over armd's.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(1, str(HERE.parent))

from daqp_lm import QPRefiner  # noqa: E402

from armd import robots  # noqa: E402
from armd.solvers.arm import arm_state  # noqa: E402
from armd.solvers.lm import refine_chain  # noqa: E402


class OSQPRefiner(QPRefiner):
    """armd's iteration with each step's QP solved by OSQP through qpsolvers."""

    def _qp(self, H: np.ndarray, f: np.ndarray, q: np.ndarray, step: float = math.inf) -> np.ndarray:
        import qpsolvers
        import scipy.sparse as sp

        lo = np.maximum(self.lower - q, -step)
        hi = np.minimum(self.upper - q, step)
        G = h = None
        if len(self.C):
            cq = self.C @ q
            G = sp.csc_matrix(np.vstack([self.C, -self.C]))
            h = np.concatenate([self.c_hi - cq, cq - self.c_lo])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            x = qpsolvers.solve_qp(
                sp.csc_matrix(H),
                f,
                G,
                h,
                lb=lo,
                ub=hi,
                solver="osqp",
                eps_abs=1e-9,
                eps_rel=1e-9,
                polish=True,
                verbose=False,
            )
        if x is None:
            return np.zeros_like(q)
        return np.clip(x, lo, hi)


def placo_solver(arm: robots.Robot):  # type: ignore[no-untyped-def]
    import placo

    robot = placo.RobotWrapper(str(arm.folder / "robot.urdf"), placo.Flags.ignore_collisions)
    solver = placo.KinematicsSolver(robot)
    solver.mask_fbase(True)
    solver.enable_joint_limits(True)
    solver.enable_velocity_limits(False)
    task = solver.add_position_task(arm.tool_frame, np.zeros(3))
    task.configure("tool", "soft", 1.0)
    return robot, solver, task


def run(arm: robots.Robot, method: str, starts: np.ndarray, targets: np.ndarray) -> dict[str, float]:
    times, iters, ok = [], [], 0
    if method == "placo":
        robot, solver, task = placo_solver(arm)
        names = list(arm.joint_names)
        for q0, t in zip(starts, targets, strict=True):
            for j, name in enumerate(names):
                robot.set_joint(name, float(q0[j]))
            robot.update_kinematics()
            task.target_world = t
            t0 = time.perf_counter_ns()
            k = 0
            for k in range(1, 201):  # noqa: B007
                try:
                    solver.solve(True)
                except RuntimeError:  # PlaCo's QP infeasible: counted as a failure
                    break
                robot.update_kinematics()
                if np.linalg.norm(robot.get_T_world_frame(arm.tool_frame)[:3, 3] - t) <= 1e-9:
                    break
            times.append(time.perf_counter_ns() - t0)
            q = np.array([robot.get_joint(n) for n in names])
            iters.append(k)
            ok += np.linalg.norm(arm.fk(q) - t) <= 1e-9 and arm.limits.contains(q, tol=1e-12)
    elif method == "armd":
        chain = arm_state(arm).packed_chain
        for q0, t in zip(starts, targets, strict=True):
            q = q0.copy()
            t0 = time.perf_counter_ns()
            err, _, its = refine_chain(chain, t, 0.0, 0.0, q, 200, 1.0, 1e-10)
            times.append(time.perf_counter_ns() - t0)
            iters.append(its)
            ok += err <= 1e-9 and np.linalg.norm(arm.fk(q) - t) <= 1e-9 and arm.limits.contains(q, tol=0.0)
    else:
        refiner = QPRefiner(arm) if method == "daqp" else OSQPRefiner(arm)
        for q0, t in zip(starts, targets, strict=True):
            t0 = time.perf_counter_ns()
            r = refiner.solve(t, q0, tol=1e-10)
            times.append(time.perf_counter_ns() - t0)
            iters.append(r.iterations)
            ok += r.position_error <= 1e-9 and arm.limits.contains(r.q, tol=0.0)
    us = np.array(times) / 1e3
    return {
        "success": ok / len(starts),
        "median_us": float(np.median(us)),
        "p99_us": float(np.percentile(us, 99)),
        "iterations": float(np.median(iters)),
    }


@contextlib.contextmanager
def quiet_stdout():  # type: ignore[no-untyped-def]
    """OSQP's C code prints to file descriptor 1; keep the table readable."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(devnull)
        os.close(saved)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300, help="refinements per arm and method")
    ap.add_argument("--spread", type=float, default=0.1, help="start offset from a solution [rad]")
    ap.add_argument("--methods", default="armd,daqp,osqp,placo")
    args = ap.parse_args()
    rng = np.random.default_rng(2026)
    print("| arm | method | success @1e-9 m | median us | p99 us | median iterations | vs armd (median) |")
    print("|---|---|---|---|---|---|---|")
    # the catalogue, and the vendors' arms of examples/arms (the myCobot 280: six joints)
    arms = [robots.load(name) for name in robots.names()]
    arms += [robots.load_folder(HERE.parent / "examples" / "arms" / f) for f in ("so101-vendor", "mycobot280")]
    for arm in arms:
        name = arm.name
        lim = arm.limits
        qs = rng.uniform(lim.lower, lim.upper, size=(20 * args.n, arm.nq))
        qs = qs[lim.contains_batch(qs, tol=0.0)][: args.n]
        targets = np.array([arm.fk(q) for q in qs])
        starts = np.clip(qs + rng.uniform(-args.spread, args.spread, size=qs.shape), lim.lower, lim.upper)
        starts = np.array([QPRefiner(arm).project(s) for s in starts])
        base = None
        for method in args.methods.split(","):
            if method == "placo" and any(
                arm.model.joints[i].shortname() == "JointModelMimic" for i in range(arm.model.njoints)
            ):
                print(f"| {name} | placo | (mimic joints: not supported by PlaCo's URDF parser) | | | | |")
                continue
            with quiet_stdout():
                res = run(arm, method, starts, targets)
            base = res["median_us"] if method == "armd" else base
            ratio = f"{res['median_us'] / base:.1f}x" if base else ""
            print(
                f"| {name} | {method} | {100 * res['success']:.1f}% | {res['median_us']:.0f} | "
                f"{res['p99_us']:.0f} | {res['iterations']:.0f} | {ratio} |"
            )


if __name__ == "__main__":
    main()
