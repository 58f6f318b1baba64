"""armd's numerical stage until issue 16, kept as a peer for ``bench/qp.py``: a Python
Levenberg-Marquardt on the exact Pinocchio model, each step a QP solved by DAQP.

Seed 004 refines its analytic answer with a Jacobian-transpose iteration. This iteration
solves, at every step, the QP

    min_dq  1/2 |J dq - e|^2 + w^2/2 |J_pitch dq - e_pitch|^2 + mu/2 |dq|^2
    s.t.    max(lower - q, -step) <= dq <= min(upper - q, step)       (box limits, trust region)
            c_lo - C q <= C dq <= c_hi - C q                            (coupled limits)

with DAQP (a dual active-set solver for small dense QPs, ~10 us a step). armd now runs the
same QP in its own compiled loop (``solvers/lm.py`` over ``solvers/activeset.py``): the
Python calls to Pinocchio and DAQP cost some 100 us a refinement, and a failed DAQP step
raised here (``QPError``) where the compiled loop retries it with more damping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import daqp
import numpy as np
import pinocchio as pin

from armd.robots import Robot
from armd.robots.angles import wrap
from armd.robots.types import FloatArray

_LOCAL = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_MARGIN = 1e-12  # [rad]


class QPError(RuntimeError):
    """DAQP failed on a step."""


@dataclass(frozen=True)
class Refined:
    """Where the iteration ended: ``q`` [rad], position error [m], pitch error [rad], iterations."""

    q: FloatArray
    position_error: float
    pitch_error: float
    iterations: int


class QPRefiner:
    """Constrained Gauss-Newton IK for one robot (thread-safe: it uses the robot's per-thread Data)."""

    def __init__(self, robot: Robot, *, step: float = 0.4) -> None:
        self.robot = robot
        self.model = robot.model
        self.fid = robot.tool_frame_id
        self.n = robot.nq
        self.lower = robot.limits.lower.copy()
        self.upper = robot.limits.upper.copy()
        self.step = step
        coupled = robot.limits.coupled
        self.C = np.array([c.coefficients for c in coupled]).reshape(len(coupled), self.n)
        # a hair inside the coupled limits, so that rounding never leaves them
        self.c_lo = np.array([c.lower + _MARGIN for c in coupled])
        self.c_hi = np.array([c.upper - _MARGIN for c in coupled])
        self.sense = np.zeros(self.n + len(coupled), dtype=np.int32)
        g = robot.geometry
        self.has_pitch = g is not None and g.wrist is not None  # a wrist pitch joint: the pitch is a task

    def project(self, q: FloatArray) -> FloatArray:
        """The point of the limit set (box and coupled) nearest ``q`` [rad]."""
        inside = self.robot.limits.clip(q)
        if not len(self.C) or self.robot.limits.contains(inside):
            return inside
        dq = self._qp(np.eye(self.n), inside - q, inside)
        return self.robot.limits.clip(inside + dq)

    def _qp(self, H: FloatArray, f: FloatArray, q: FloatArray, step: float = math.inf) -> FloatArray:
        lo = np.maximum(self.lower - q, -step)
        hi = np.minimum(self.upper - q, step)
        if len(self.C):
            cq = self.C @ q
            bu = np.concatenate([hi, self.c_hi - cq])
            bl = np.concatenate([lo, self.c_lo - cq])
        else:
            bu, bl = hi, lo
        x, _fval, exitflag, _info = daqp.solve(H, f, self.C, bu, bl, self.sense)
        if exitflag < 1:
            raise QPError(f"QP step failed (DAQP exit flag {exitflag}) on {self.robot.name}")
        return np.asarray(x)

    def _evaluate(
        self, q: FloatArray, target: FloatArray, pitch: float | None, w2: float, jacobian: bool
    ) -> tuple[float, FloatArray, float, FloatArray | None, FloatArray | None]:
        """(cost, position error vector [m], pitch error [rad], position Jacobian and pitch
        gradient (or None)) at ``q``."""
        data = self.robot.data()
        if jacobian:
            pin.computeJointJacobians(self.model, data, q)
        else:
            pin.forwardKinematics(self.model, data, q)
        placement = pin.updateFramePlacement(self.model, data, self.fid)
        e = target - placement.translation
        perr = 0.0
        if pitch is not None and self.has_pitch:
            perr = wrap(pitch - self.robot._pitch(q, placement.rotation))
        cost = float(e @ e) + w2 * perr * perr
        if not jacobian:
            return cost, e, perr, None, None
        J = pin.getFrameJacobian(self.model, data, self.fid, _LOCAL)
        row = self._pitch_gradient(q, np.asarray(placement.rotation), J[3:]) if self.has_pitch else None
        return cost, e, perr, np.array(J[:3]), row

    def _pitch_gradient(self, q: FloatArray, rotation: FloatArray, angular: FloatArray) -> FloatArray:
        """d(tool pitch)/dq [rad/rad] (:meth:`Robot.tool_pitch`), from the frame's angular Jacobian:
        the tool axis d turns at w_j x d per joint, and the arm's heading with the yaw."""
        d = rotation @ self.robot.tool_axis
        dd = np.cross(angular.T, d).T  # (3, n): d(d)/dq
        g = self.robot.geometry
        if g is not None:
            heading = g.heading(q)
            f = np.array([math.cos(heading), math.sin(heading), 0.0])
            a = float(d @ f)
            da = f @ dd
            da[g.yaw] += g.sign[0] * float(d @ np.array([-f[1], f[0], 0.0]))
        else:
            a = math.hypot(d[0], d[1])
            da = (d[0] * dd[0] + d[1] * dd[1]) / max(a, 1e-300)
        b = float(d[2])
        return np.asarray((a * dd[2] - b * da) / max(a * a + b * b, 1e-300))

    def solve(
        self,
        target: FloatArray,
        q0: FloatArray,
        *,
        pitch: float | None = None,
        pitch_weight: float = 0.1,
        tol: float = 1e-12,
        max_iter: int = 60,
    ) -> Refined:
        """Iterate from ``q0`` (projected into the limits first) toward ``target`` [m].

        Levenberg-Marquardt: a step is taken only if it lowers the cost (else the damping
        grows and the QP is solved again), so the error never increases. ``pitch`` [rad],
        when given, is a second task weighted by ``pitch_weight`` [m/rad]. Stops when the
        position error is below ``tol`` [m] (and the pitch error below ``tol`` [rad]), or
        when no step lowers the cost any more (a constrained optimum).
        """
        q = self.project(np.asarray(q0, dtype=float))
        use_pitch = pitch is not None and self.has_pitch
        w2 = pitch_weight * pitch_weight if use_pitch else 0.0
        ptarget = pitch if use_pitch else None
        cost, e, perr, J, row = self._evaluate(q, target, ptarget, w2, True)
        mu = 1e-6
        it = 0
        for it in range(1, max_iter + 1):
            if math.sqrt(float(e @ e)) <= tol and abs(perr) <= tol:
                it -= 1
                break
            assert J is not None
            H = J.T @ J
            g = J.T @ e
            if use_pitch:
                assert row is not None
                H = H + w2 * np.outer(row, row)
                g = g + w2 * perr * row
            accepted = False
            for _ in range(12):
                Hd = H.copy()
                Hd[np.diag_indices_from(Hd)] += mu
                dq = self._qp(Hd, -g, q, self.step)
                q_new = self.robot.limits.clip(q + dq)
                cost_new, e_new, perr_new, _, _ = self._evaluate(q_new, target, ptarget, w2, False)
                if cost_new < cost:
                    accepted = True
                    break
                mu *= 10.0
            if not accepted:
                break  # no descent direction inside the limits: a constrained optimum
            progress = cost - cost_new
            q, e, perr = q_new, e_new, perr_new
            cost = cost_new
            mu = max(mu / 10.0, 1e-12)
            if progress <= 1e-12 * max(cost, 1e-300) or float(np.max(np.abs(dq))) < 1e-13:
                break
            _, e, perr, J, row = self._evaluate(q, target, ptarget, w2, True)
        return Refined(q, math.sqrt(float(e @ e)), abs(perr), it)
