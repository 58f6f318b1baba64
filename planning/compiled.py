"""The planner's per-sample arithmetic, compiled: Ruckig phases to samples, and the gate's fast "all clear".

A trajectory has tens to hundreds of samples of a few joints, where NumPy spends its time
in call overhead rather than arithmetic. Two compiled loops do the work:

* :func:`evaluate`: every sample's position, velocity and acceleration from the segments'
  constant-jerk phase tables (:func:`planning.ruckig_path.phase_table`), the same
  expressions in the same order as Ruckig's ``at_time``, and the forward-difference jerk;
* :func:`all_clear`: True when every sample is finite and inside every limit (box,
  coupled, velocity, acceleration, jerk, actuator angle and command ranges) with a margin,
  writing the actuator commands as it goes.

``all_clear`` only answers "clearly fine". Anything else (a violation, or a value within a
hair of a limit) goes to the exact checks of :mod:`planning.checks`, which decide and name
the joint, time and value: the compiled loop can make a plan faster, never let one through
that the checks would refuse.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray
from armd.solvers.jit import entry

IntArray = NDArray[np.int64]

MARGIN = 1e-12  # [rad, rad/s ...]: all_clear is stricter than the checks by this much


@entry("void(f8[:, :, :, :], f8[:], f8[:], f8[:], f8, f8[:, :], f8[:, :], f8[:, :], f8[:, :])")
def evaluate(
    tables: FloatArray,
    seg_starts: FloatArray,
    seg_durations: FloatArray,
    times: FloatArray,
    dt: float,
    P: FloatArray,
    V: FloatArray,
    A: FloatArray,
    Jk: FloatArray,
) -> None:
    """Fill P, V, A (samples x dofs) at ``times`` (clamped to the path), and Jk with
    (A[k+1] - A[k]) / dt (0 on the last sample).

    ``tables[s, d]``: segment s, dof d: rows (duration, jerk, a0, v0, p0) of its phases,
    zero-length rows in front. Past the last phase (a segment's duration is rounded up to
    whole cycles), the end state carries on at constant acceleration, as in Ruckig's at_time.
    """
    nseg, dofs, phases = tables.shape[0], tables.shape[1], tables.shape[2]
    total = seg_starts[nseg - 1] + seg_durations[nseg - 1]
    for i in range(times.shape[0]):
        t = min(max(times[i], 0.0), total)
        s = 0
        for k in range(nseg):  # the last segment that starts at or before t
            if seg_starts[k] <= t:
                s = k
        local = min(t - seg_starts[s], seg_durations[s])
        for d in range(dofs):
            start = 0.0
            row = 0
            row_start = 0.0
            for ph in range(phases):  # the last phase that starts at or before local
                if start <= local:
                    row = ph
                    row_start = start
                else:
                    break
                start += tables[s, d, ph, 0]
            j = tables[s, d, row, 1]
            a0 = tables[s, d, row, 2]
            v0 = tables[s, d, row, 3]
            p0 = tables[s, d, row, 4]
            h = local - row_start
            if row == phases - 1 and local > start:  # past the last phase: its end state, at constant acceleration
                T = tables[s, d, row, 0]
                p0, v0, a0 = p0 + T * (v0 + T * (a0 / 2 + T * j / 6)), v0 + T * (a0 + T * j / 2), a0 + T * j
                j = 0.0
                h = local - start
            P[i, d] = p0 + h * (v0 + h * (a0 / 2 + h * j / 6))
            V[i, d] = v0 + h * (a0 + h * j / 2)
            A[i, d] = a0 + h * j
    n = times.shape[0]
    for i in range(n):
        for d in range(dofs):
            Jk[i, d] = (A[i + 1, d] - A[i, d]) / dt if i + 1 < n else 0.0


@entry("b1(f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:], i8[:, :])")
def all_clear(
    P: FloatArray,
    V: FloatArray,
    A: FloatArray,
    Jk: FloatArray,
    coupled: FloatArray,
    angles: FloatArray,
    joints: FloatArray,
    couplings: FloatArray,
    actuators: FloatArray,
    tolerances: FloatArray,
    commands: IntArray,
) -> bool:
    """True when every sample is clearly inside every limit (by MARGIN more than the checks
    ask); ``commands`` gets rint(angle * gain + bias).

    ``coupled`` (samples x coupled limits) and ``angles`` (samples x actuators) are the
    samples' coupled-limit values and actuator angles. The limits, packed (few arguments:
    each costs a compiled call some time): ``joints`` rows lower, upper, vmax, amax, jmax;
    ``couplings`` rows lower, upper; ``actuators`` rows angle lo, angle hi, gain, bias,
    command lo, command hi; ``tolerances`` = (position, rate (relative), actuator angle).
    """
    position_tol, rate_tol, angle_tol = tolerances[0], tolerances[1], tolerances[2]
    n, dofs = P.shape[0], P.shape[1]
    for i in range(n):
        for d in range(dofs):
            p, v, a, jk = P[i, d], V[i, d], A[i, d], Jk[i, d]
            if not (np.isfinite(p) and np.isfinite(v) and np.isfinite(a) and np.isfinite(jk)):
                return False
            if p < joints[0, d] - position_tol + MARGIN or p > joints[1, d] + position_tol - MARGIN:
                return False
            if (
                abs(v) > joints[2, d] * (1 + rate_tol) - MARGIN
                or abs(a) > joints[3, d] * (1 + rate_tol) - MARGIN
                or abs(jk) > joints[4, d] * (1 + rate_tol) - MARGIN
            ):
                return False
        for c in range(coupled.shape[1]):
            x = coupled[i, c]
            if not (x >= couplings[0, c] - position_tol + MARGIN and x <= couplings[1, c] + position_tol - MARGIN):
                return False
        for k in range(angles.shape[1]):
            x = angles[i, k]
            if not (x >= actuators[0, k] - angle_tol + MARGIN and x <= actuators[1, k] + angle_tol - MARGIN):
                return False
            cmd = np.rint(x * actuators[2, k] + actuators[3, k])
            if cmd < actuators[4, k] or cmd > actuators[5, k]:
                return False
            commands[i, k] = np.int64(cmd)
    return True
