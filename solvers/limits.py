"""Joint limits as the compiled solvers check them: box (with a slack that the caller clamps
away) and coupled rows ``clo <= C q <= chi`` (exactly: no slack)."""

from __future__ import annotations

from armd.robots.types import FloatArray

from .arrays import Family
from .jit import jit
from .kinematics import Chain


@jit
def limits_ok(q: FloatArray, f: Family | Chain, tol: float) -> bool:
    """Box limits hold to ``tol`` [rad] and every coupled limit holds exactly (``f``'s limits:
    a family's, in its angles, or a chain's, in the URDF's)."""
    lower, upper, C, clo, chi = f.lower, f.upper, f.C, f.clo, f.chi
    for i in range(q.shape[0]):
        if q[i] < lower[i] - tol or q[i] > upper[i] + tol:
            return False
    for r in range(C.shape[0]):
        v = 0.0
        for i in range(q.shape[0]):
            v += C[r, i] * q[i]
        if v < clo[r] or v > chi[r]:
            return False
    return True
