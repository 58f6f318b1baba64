"""Joint limits: the box ``lower <= q <= upper`` and coupled linear limits ``A q <= b``.

Coupled limits come from linkages (the desk4's level-keeping linkage bounds ``q2 + q3``).
Each is written in ``robot.toml`` as ``lower <= sum(c_i q_i) <= upper`` and kept here as
two rows of ``A q <= b``, the form a QP takes as hard inequality constraints.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from armd.errors import CoupledLimitError, JointLimitError, LimitError

from .types import FloatArray


@dataclass(frozen=True)
class CoupledLimit:
    """``lower <= coefficients . q <= upper`` over the joint vector [rad]."""

    name: str
    coefficients: FloatArray
    lower: float
    upper: float

    def value(self, q: FloatArray) -> float:
        return float(self.coefficients @ q)


@dataclass(frozen=True)
class JointLimits:
    """Position, velocity, acceleration and jerk limits of an arm, in joint order.

    Units: positions [rad], velocities [rad/s], accelerations [rad/s^2], jerks [rad/s^3].
    """

    names: tuple[str, ...]
    lower: FloatArray
    upper: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    jerk: FloatArray
    coupled: tuple[CoupledLimit, ...] = ()

    @property
    def A(self) -> FloatArray:  # noqa: N802 (the conventional name)
        """Rows of ``A q <= b`` for the coupled limits, shape (2 k, n)."""
        n = len(self.names)
        if not self.coupled:
            return np.zeros((0, n))
        rows = [c.coefficients for c in self.coupled] + [-c.coefficients for c in self.coupled]
        return np.array(rows, dtype=float)

    @property
    def b(self) -> FloatArray:
        """Right-hand side of ``A q <= b``, shape (2 k,)."""
        if not self.coupled:
            return np.zeros(0)
        return np.array([c.upper for c in self.coupled] + [-c.lower for c in self.coupled])

    def violations(self, q: FloatArray, tol: float = 1e-9) -> list[JointLimitError | CoupledLimitError]:
        """Every limit that ``q`` breaks by more than ``tol``, as the errors that name them."""
        out: list[JointLimitError | CoupledLimitError] = []
        for i, name in enumerate(self.names):
            if not (self.lower[i] - tol <= q[i] <= self.upper[i] + tol):
                out.append(JointLimitError(name, float(q[i]), (float(self.lower[i]), float(self.upper[i]))))
        for c in self.coupled:
            v = c.value(q)
            if not (c.lower - tol <= v <= c.upper + tol):
                out.append(CoupledLimitError(c.name, v, (c.lower, c.upper)))
        return out

    def contains(self, q: FloatArray, tol: float = 1e-9) -> bool:
        """True when ``q`` is within every position limit, box and coupled, to ``tol``."""
        values = q.tolist() if isinstance(q, np.ndarray) else list(q)  # plain floats: no NumPy overhead per call
        for v, lo, hi in zip(values, self._lower, self._upper, strict=True):
            if not lo - tol <= v <= hi + tol:  # (NaN fails too)
                return False
        for c in self.coupled:
            v = sum(k * x for k, x in zip(c.coefficients.tolist(), values, strict=True))
            if not c.lower - tol <= v <= c.upper + tol:
                return False
        return True

    @functools.cached_property
    def _lower(self) -> list[float]:
        return self.lower.tolist()

    @functools.cached_property
    def _upper(self) -> list[float]:
        return self.upper.tolist()

    def check(self, q: FloatArray, tol: float = 1e-9) -> None:
        """Raise the first limit error of ``q``, if any."""
        errors = self.violations(q, tol)
        if errors:
            raise errors[0]

    def in_box(self, q: FloatArray, tol: float = 1e-9) -> bool:
        """True when ``q`` is within the box limits (not the coupled ones), to ``tol``."""
        return bool(np.all((q >= self.lower - tol) & (q <= self.upper + tol)))

    def clip(self, q: FloatArray) -> FloatArray:
        """``q`` brought into the box limits (each joint to its nearer bound)."""
        return np.minimum(np.maximum(q, self.lower), self.upper)

    def first_outside(self, qs: FloatArray, tol: float = 1e-9) -> tuple[int, LimitError] | None:
        """The first row of ``qs`` (shape (m, n), samples in order) outside a box limit, else the
        first outside a coupled limit (in their order), with the error that names the limit;
        None if every row is inside, to ``tol``."""
        bad = (qs < self.lower - tol) | (qs > self.upper + tol)
        if bad.any():
            k, j = (int(x) for x in np.argwhere(bad)[0])
            return k, JointLimitError(self.names[j], float(qs[k, j]), (float(self.lower[j]), float(self.upper[j])))
        for c in self.coupled:
            v = qs @ c.coefficients
            over = (v < c.lower - tol) | (v > c.upper + tol)
            if over.any():
                k = int(np.argmax(over))
                return k, CoupledLimitError(c.name, float(v[k]), (c.lower, c.upper))
        return None

    def contains_batch(self, qs: FloatArray, tol: float = 1e-9) -> NDArray[np.bool_]:
        """Vectorised :meth:`contains` over rows of ``qs``, shape (m, n) -> (m,)."""
        ok = np.all((qs >= self.lower - tol) & (qs <= self.upper + tol), axis=1)
        for c in self.coupled:
            v = qs @ c.coefficients
            ok &= (v >= c.lower - tol) & (v <= c.upper + tol)
        return ok
