"""The enumerated closest point (solvers.closest.closest_level) for an arm without a wrist whose
pivot is offset sideways and whose limits couple the shoulder and elbow (desk4): within every
limit, exactly what it reports, and never beaten by the iteration or by a dense grid.

The grid here is written independently of the solver: planar poses on a grid over the box (the
coupled limits filtered), each with its best yaw by the elementary fact that ``a - b cos(yaw -
c)``, b >= 0, is least on an interval at ``c`` if inside, else at an end.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import plain

from armd import robots
from armd.solvers import solve_ik
from armd.solvers.arm import arm_state as _arm
from armd.solvers.arrays import Family
from armd.solvers.closest import closest_box, closest_family
from armd.solvers.lm import refine_family
from armd.solvers.packed import Packed, pack

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ARM = plain("desk4")
N_TARGETS = 2000
KINDS = ("beyond reach", "near the yaw axis", "above or below", "behind the base", "anywhere")


def _reach(arm: robots.Robot) -> float:
    """The largest distance of the tool from the base origin over the atlas [m]."""
    return float(np.max(np.linalg.norm(_arm(arm).atlas.p, axis=1)))


def _candidate(kind: str, reach: float, rng: np.random.Generator) -> np.ndarray:
    """A target of one kind; it may be reachable (the caller keeps the unreachable ones)."""
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    if kind == "beyond reach":  # every direction, 1.05-2x the reach
        return d * reach * rng.uniform(1.05, 2.0)
    if kind == "near the yaw axis":  # 1 um to 1 cm off it, at any height
        off, turn = 10 ** rng.uniform(-6, -2), rng.uniform(-math.pi, math.pi)
        return np.array([off * math.cos(turn), off * math.sin(turn), rng.uniform(-2.0, 2.0) * reach])
    if kind == "above or below":
        return np.array([*rng.uniform(-0.1, 0.1, 2), rng.choice([-1.0, 1.0]) * rng.uniform(1.05, 2.0) * reach])
    if kind == "behind the base":  # the bearing beyond the steer's +-pi/2
        d[0] = -abs(d[0])
        return d * rng.uniform(0.02, 2.0) * reach
    return d * rng.uniform(0.0, 2.0) * reach  # anywhere: also the holes of the workspace


@pytest.fixture(scope="module")
def targets() -> list[np.ndarray]:
    """N_TARGETS unreachable targets for desk4, the kinds in turn, and three on the yaw axis."""
    rng = np.random.default_rng(31)
    reach = _reach(ARM)
    out = [np.array([0.0, 0.0, 0.9]), np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 0.02])]
    while len(out) < N_TARGETS:
        t = _candidate(KINDS[len(out) % len(KINDS)], reach, rng)
        if solve_ik(ARM, t).status == "unreachable":
            out.append(t)
    return out


def _family(
    P: np.ndarray,
    J: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    C: np.ndarray,
    clo: np.ndarray,
    chi: np.ndarray,
    exact_pitch_search: bool = False,
) -> Packed:
    """desk4's family with these numbers (the compiled code's tuple, packed; the family's angles are
    the URDF's)."""
    return pack(_family_tuple(P, J, lower, upper, C, clo, chi, exact_pitch_search))


def _family_tuple(
    P: np.ndarray,
    J: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    C: np.ndarray,
    clo: np.ndarray,
    chi: np.ndarray,
    exact_pitch_search: bool = False,
) -> Family:
    c = np.ascontiguousarray
    w = _arm(ARM).weights
    return Family(
        c(P),
        c(J),
        c(lower),
        c(upper),
        c(w),
        c(C, dtype=float),
        c(clo, dtype=float),
        c(chi, dtype=float),
        exact_pitch_search,
        False,
    )


def _enumerated(
    P: np.ndarray,
    J: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    C: np.ndarray,
    clo: np.ndarray,
    chi: np.ndarray,
    target: np.ndarray,
    ref: np.ndarray,
) -> tuple[float, np.ndarray]:
    q = np.empty(len(ref))
    err = closest_box(_family(P, J, lower, upper, C, clo, chi), target, np.ascontiguousarray(ref), q, True)
    return err, q


def _iterated(
    P: np.ndarray,
    J: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    C: np.ndarray,
    clo: np.ndarray,
    chi: np.ndarray,
    target: np.ndarray,
    starts: np.ndarray,
) -> float:
    """The best error of the Levenberg-Marquardt iteration from each start."""
    best = math.inf
    f = _family(P, J, lower, upper, C, clo, chi)
    for q0 in starts:
        q = q0.copy()
        err, _, _ = refine_family(f, target, 0.0, 0.0, q, 1000, 0.4, 1e-12)
        best = min(best, err)
    return best


class Grid:
    """Planar poses on a grid within the limits (no wrist; coupled rows on the planar joints only)."""

    def __init__(
        self,
        P: np.ndarray,
        J: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
        C: np.ndarray,
        clo: np.ndarray,
        chi: np.ndarray,
        n1: int = 601,
        n2: int = 751,
    ) -> None:
        t1, t2 = np.meshgrid(
            np.linspace(lower[J[1]], upper[J[1]], n1), np.linspace(lower[J[2]], upper[J[2]], n2), indexing="ij"
        )
        t1, t2 = t1.ravel(), t2.ravel()
        keep = np.ones(len(t1), dtype=bool)
        for r in range(len(C)):
            v = C[r, J[1]] * t1 + C[r, J[2]] * t2
            keep &= (v >= clo[r]) & (v <= chi[r])
        t1, t2 = t1[keep], t2[keep]
        px, self.py, pz, l1, l2, _, ox, oz = P
        self.u = px + ox + l1 * np.cos(t1) + l2 * np.cos(t1 + t2)
        self.z = pz + oz + l1 * np.sin(t1) + l2 * np.sin(t1 + t2)
        self.ylo, self.yhi = lower[J[0]], upper[J[0]]

    def error(self, target: np.ndarray) -> float:
        x, y, z = target
        aim = math.atan2(y, x) - np.arctan2(self.py, self.u)
        aim = self.ylo + np.remainder(aim - self.ylo, 2 * math.pi)  # its turn at or above the lower limit
        best = math.inf
        for yaw in (
            np.full_like(self.u, self.ylo),
            np.full_like(self.u, self.yhi),
            np.where(aim <= self.yhi, aim, self.ylo),
        ):
            c, s = np.cos(yaw), np.sin(yaw)
            d2 = (c * self.u - s * self.py - x) ** 2 + (s * self.u + c * self.py - y) ** 2 + (self.z - z) ** 2
            best = min(best, float(d2.min()))
        return math.sqrt(best)


def test_desk4_unreachable_targets_are_enumerated(targets: list[np.ndarray]) -> None:
    """No iteration: every answer within every limit, its error what Pinocchio's FK says."""
    for t in targets:
        r = solve_ik(ARM, t)
        assert r.status == "unreachable" and r.iterations == 0, t.tolist()
        assert ARM.limits.contains(r.q, tol=0.0), (t.tolist(), ARM.limits.violations(r.q, 0.0))
        assert math.isclose(r.position_error, float(np.linalg.norm(ARM.fk(r.q) - t)), rel_tol=1e-12, abs_tol=1e-15)


def test_desk4_closest_point_is_never_worse_than_the_iteration(targets: list[np.ndarray]) -> None:
    """12 atlas starts per target (the 6 whose tool points are nearest it and 6 at random), each
    iterated to convergence: none ends nearer than the enumeration."""
    a = _arm(ARM)
    fp = a.family
    assert fp is not None and a.exact  # the family's formula is the URDF's FK
    rng = np.random.default_rng(32)
    beaten = 0
    for t in targets:
        err, _ = _enumerated(fp.P, fp.J, fp.lower, fp.upper, fp.C, fp.clo, fp.chi, t, ARM.neutral)
        assert err >= 0.0
        near = np.argsort(np.linalg.norm(a.atlas.p - t, axis=1))[:6]
        starts = a.atlas.q[np.concatenate([near, rng.choice(len(a.atlas.q), 6, replace=False)])]
        other = _iterated(fp.P, fp.J, fp.lower, fp.upper, fp.C, fp.clo, fp.chi, t, starts)
        assert err <= other + 1e-9, (t.tolist(), err, other)
        beaten += err < other - 1e-9
    assert beaten > 0  # the iteration stops in local minima now and then: the enumeration does not


def test_desk4_closest_point_is_never_worse_than_a_dense_grid(targets: list[np.ndarray]) -> None:
    a = _arm(ARM)
    fp = a.family
    assert fp is not None
    grid = Grid(fp.P, fp.J, fp.lower, fp.upper, fp.C, fp.clo, fp.chi)
    for t in targets[:200]:
        err, _ = _enumerated(fp.P, fp.J, fp.lower, fp.upper, fp.C, fp.clo, fp.chi, t, ARM.neutral)
        assert err <= grid.error(t) + 1e-9, t.tolist()


def _variant(name: str) -> tuple[np.ndarray, ...]:
    """desk4's numbers changed to reach the parts of the enumeration desk4 itself does not: no
    offset, a larger one on the other side, an elbow that can straighten and fold (the singular
    lines inside the polygon), limits on one planar joint written as coupled rows with other
    scales and signs, a yaw that turns all the way round."""
    a = _arm(ARM)
    fp = a.family
    assert fp is not None
    P, lower, upper = fp.P.copy(), fp.lower.copy(), fp.upper.copy()
    C, clo, chi = fp.C.copy(), fp.clo.copy(), fp.chi.copy()
    if name == "no offset":
        P[1] = 0.0
    elif name == "large offset":
        P[1] = -0.05
    elif name == "straight and folded elbow":
        lower[2], upper[2] = -3.6, 0.6
    elif name == "scaled rows":
        C = np.array([[0.0, -2.0, -2.0], [0.0, 0.0, 3.0], [0.0, 0.5, 0.0]])
        clo, chi = np.array([-1.8, -6.0, 0.1]), np.array([2.4, 0.0, 0.9])
    elif name == "yaw all round":
        lower[0], upper[0] = -4.0, 4.0
    return P, fp.J, lower, upper, C, clo, chi


@pytest.mark.parametrize(
    "name", ["no offset", "large offset", "straight and folded elbow", "scaled rows", "yaw all round"]
)
def test_other_planar_limits_are_enumerated_exactly(name: str) -> None:
    """On the family's formula (the exact model of such an arm): targets reachable or not, the
    enumeration is within every limit and never worse than 12 iterations or the grid."""
    P, J, lower, upper, C, clo, chi = _variant(name)
    rng = np.random.default_rng(33)
    qs = rng.uniform(lower, upper, size=(20000, 3))
    inside = np.all((qs @ C.T >= clo) & (qs @ C.T <= chi), axis=1)
    starts = qs[inside][:1000]
    grid = Grid(P, J, lower, upper, C, clo, chi, 301, 401)
    reach = _reach(ARM)
    for i in range(150):
        t = _candidate(KINDS[i % len(KINDS)], reach, rng)
        ref = starts[i]
        err, q = _enumerated(P, J, lower, upper, C, clo, chi, t, ref)
        assert err >= 0.0, t.tolist()
        assert np.all(q >= lower) and np.all(q <= upper) and np.all(C @ q >= clo) and np.all(C @ q <= chi)
        other = _iterated(P, J, lower, upper, C, clo, chi, t, starts[rng.choice(len(starts), 12, replace=False)])
        assert err <= other + 1e-9, (t.tolist(), err, other)
        assert err <= grid.error(t) + 1e-9, t.tolist()


def test_limits_it_does_not_cover_fall_back_to_the_iteration() -> None:
    """A coupled limit touching the yaw, or mixing shoulder and elbow in another ratio (its edge
    is no circle), or a wrist arm with an offset pivot: -1, and closest_family iterates."""
    a = _arm(ARM)
    fp = a.family
    assert fp is not None
    t = np.array([0.5, 0.2, 0.3])
    for C in (np.array([[0.1, 1.0, 1.0]]), np.array([[0.0, 1.0, 2.0]])):
        clo, chi = np.array([-1.2]), np.array([0.9])
        err, _ = _enumerated(fp.P, fp.J, fp.lower, fp.upper, C, clo, chi, t, ARM.neutral)
        assert err == -1.0
        q = np.empty(3)
        assert a.arrays is not None
        arrays = pack(a.arrays._replace(family=_family_tuple(fp.P, fp.J, fp.lower, fp.upper, C, clo, chi)))
        _, _, its = closest_family(arrays, t, 0.0, 0.0, ARM.neutral, a.packed_atlas, 3, q)
        assert its > 0
    wrist = _arm(plain("insomniac")).family
    assert wrist is not None
    P = wrist.P.copy()
    P[1] = 0.01
    q = np.empty(len(wrist.lower))
    assert closest_box(pack(wrist._replace(P=P)), t, plain("insomniac").neutral, q, True) == -1.0


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "gupta3"])
def test_pruned_enumeration_finds_what_the_full_one_finds(name: str) -> None:
    """closest_box skips a yaw or a face whose lower bound cannot beat the best so far, and
    stops a yaw at a candidate that meets its bound (the stretched arm): on 1,500 unreachable
    targets of every kind, the pruned search's error is the full search's (visiting every
    candidate), its answer within limits and where it says. A bound that is not one (a slack of
    the wrong sign, a reach too short) makes it answer worse somewhere here."""
    arm = plain(name)
    a = _arm(arm)
    fp = a.family
    assert fp is not None and a.packed_family is not None
    rng = np.random.default_rng(47)
    reach = _reach(arm)
    done = stopped_early = 0
    while done < 1500:
        t = _candidate(KINDS[done % len(KINDS)], reach, rng)
        if solve_ik(arm, t).status != "unreachable":
            continue
        ref = arm.neutral if done % 2 else rng.uniform(fp.lower, fp.upper)
        q_full, q_pruned = np.empty(arm.nq), np.empty(arm.nq)
        full = closest_box(a.packed_family, t, ref, q_full, False)
        pruned = closest_box(a.packed_family, t, ref, q_pruned, True)
        assert (full < 0) == (pruned < 0), t.tolist()
        if full >= 0:
            assert abs(pruned - full) <= 1e-12 * max(full, 1.0), (t.tolist(), full, pruned)
            assert arm.limits.contains(q_pruned, tol=0.0)
            assert math.isclose(pruned, float(np.linalg.norm(arm.fk(q_pruned) - t)), rel_tol=1e-12, abs_tol=1e-15)
            stopped_early += not np.array_equal(q_full, q_pruned)
        done += 1
    assert done == 1500
