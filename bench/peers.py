"""Solver adapters for ``bench/ik.py``: armd's own solver and the peers it is measured against.

Every adapter wraps one solver for one arm and splits a call in three, so that only the
solver itself is timed:

* ``prepare(target)``   turns the 3-D target point into what the solver takes (untimed);
* ``call(prepared, seed)``  the solver call, the only part inside ``perf_counter_ns``;
* ``answer(raw)``       turns the solver's reply into an :class:`Answer` (untimed).

The harness never trusts a solver's own verdict: it checks every answer's tool point with
``robot.fk`` and the joint limits with ``robot.limits.contains`` (box and coupled limits).

Peers:

* ``rtb``: roboticstoolbox-python's C++ Levenberg-Marquardt solver ``ETS.ik_LM`` with its
  defaults (``ilimit=30``, ``slimit=100`` random restarts, ``method="chan"``,
  ``joint_limits=True``), a position-only mask ``[1, 1, 1, 0, 0, 0]`` and a tolerance that
  means the same position error as the harness's (see :func:`rtb_tolerance`).
* ``ikpy``: ``Chain.inverse_kinematics(target_position)``, position only, with ikpy's
  defaults (SciPy ``least_squares`` inside the joint bounds, one start, no restarts).
  Tightening its ``tol`` (1e-10, 1e-12) was tried: the success rates did not change, only
  the times grew, so the defaults are used.

Each peer loads the arm's own ``robot.urdf``. Neither handles URDF *mimic* joints (desk4's
level-keeping linkage): both read them as independent joints. For such an arm the adapter
builds an equivalent chain from ``robot.geometry`` (:func:`geometry_chain`). Whatever the
source, :func:`fk_agreement` must find the peer's FK equal to ``robot.fk`` to 1e-9 m at
random in-limit configurations, or the peer is not run on that arm.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

# The peers' FK must match robot.fk this closely [m] before they are benchmarked.
FK_AGREEMENT = 1e-9


class Unavailable(Exception):
    """The solver cannot run on this arm (not installed, model mismatch ...); the message says why."""


@dataclass
class Answer:
    """What a solver returned, in armd's joint order.

    ``q`` is None when the solver gave no joint vector. ``claimed`` is the solver's own
    verdict (None when it gives none); ``status`` and ``reported_error`` are armd's fields.
    """

    q: FloatArray | None
    claimed: bool | None = None
    status: str | None = None
    reported_error: float | None = None


@dataclass(frozen=True)
class ChainJoint:
    """A joint of an equivalent serial chain: a fixed translation, then a rotation about ``axis``.

    ``index`` is the joint's position in armd's joint vector.
    """

    index: int
    origin: tuple[float, float, float]
    axis: tuple[float, float, float]


@dataclass(frozen=True)
class EquivalentChain:
    """A serial chain with the same tool *point* as the arm (orientation is not kept)."""

    joints: tuple[ChainJoint, ...]
    tip: tuple[float, float, float]
    source: str

    @property
    def indices(self) -> NDArray[np.int64]:
        return np.array([j.index for j in self.joints], dtype=np.int64)


def geometry_chain(robot: Any) -> EquivalentChain:
    """A serial chain for the tool point, built from ``robot.geometry`` (never from hard-coded numbers).

    The family's FK (``robots/geometry.py``) is::

        p = Rz(yaw) [pivot + tool_offset(out, 0, up)
                     + Ry'(phi_1) (upper_arm, 0, 0) + Ry'(phi_2) (forearm, 0, 0) + Ry'(phi_3) (hand, 0, 0)]

    with ``Ry'`` a rotation about ``-y`` (pitch joints lift) and ``phi_k`` the running sums of
    the pitch joints. ``tool_offset`` is fixed in the yaw frame (a level-keeping linkage), and
    translations commute, so it can be moved in front of the shoulder: the chain is yaw,
    translation ``pivot + offset``, shoulder, ``upper_arm``, elbow, ``forearm``, [wrist,
    ``hand``]. Its tool point equals the family's; its tool orientation does not (position-only
    IK does not use it). Joints outside the family (a wrist roll) are left out: the adapter
    keeps them at the seed, and :func:`fk_agreement` checks the result.
    """
    g = robot.geometry
    if g is None:
        raise Unavailable(f"{robot.name}: the URDF chain does not match and the arm has no [geometry] to rebuild it")
    out, up = g.tool_offset
    pitch_axis = (0.0, -1.0, 0.0)
    joints = [
        ChainJoint(g.yaw, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        ChainJoint(g.shoulder, (g.pivot[0] + out, g.pivot[1], g.pivot[2] + up), pitch_axis),
        ChainJoint(g.elbow, (g.upper_arm, 0.0, 0.0), pitch_axis),
    ]
    tip = (g.forearm, 0.0, 0.0)
    if g.wrist is not None:
        joints.append(ChainJoint(g.wrist, (g.forearm, 0.0, 0.0), pitch_axis))
        tip = (g.hand, 0.0, 0.0)
    return EquivalentChain(tuple(joints), tip, "robot.geometry (URDF has mimic joints)")


def has_mimic_joints(robot: Any) -> bool:
    """True when the arm's URDF has ``<mimic>`` joints (which the peers treat as free joints)."""
    import xml.etree.ElementTree as ET

    root = ET.parse(robot.folder / "robot.urdf").getroot()
    return any(j.find("mimic") is not None for j in root.iter("joint"))


def random_configs(robot: Any, m: int, rng: np.random.Generator, *, clear: bool = False) -> FloatArray:
    """``m`` uniformly random joint vectors inside every limit (box and coupled), by rejection;
    ``clear``: only those clear of collisions too (:func:`is_clear`)."""
    lo, hi = robot.limits.lower, robot.limits.upper
    out: list[FloatArray] = []
    while len(out) < m:
        q = rng.uniform(lo, hi, size=(max(64, 2 * (m - len(out))), len(lo)))
        q = q[robot.limits.contains_batch(q)]
        out.extend(r for r in q if not clear or is_clear(robot, r))
    return np.array(out[:m])


def is_clear(robot: Any, q: FloatArray) -> bool:
    """``q`` touches nothing in the arm's world (itself, its floor, its obstacles) and keeps the
    tool point above the floor: a configuration whose tool point armd's IK must answer ``ok``
    (the peers know no collisions: the targets they are measured on come from such ones)."""
    world = robot.collision
    if world is None:
        return True
    if world.ground is not None and float(robot.fk(q)[2]) < world.ground:
        return False
    return world.first_contact(q) is None


def configs_at_limits(robot: Any, m: int, rng: np.random.Generator, *, clear: bool = False) -> FloatArray:
    """``m`` in-limit joint vectors with joints pinned on their limits: where solvers tend to fail.

    Each joint sits on its lower or upper bound with probability 1/2; each coupled limit is
    made active (one of its joints moved so the sum sits on the bound) with probability 1/2.
    Vectors that leave another limit (or, with ``clear``, collide) are drawn again.
    """
    lo, hi = robot.limits.lower, robot.limits.upper
    out: list[FloatArray] = []
    while len(out) < m:
        k = max(64, 2 * (m - len(out)))
        q = random_configs(robot, k, rng)
        pin = rng.random(q.shape) < 0.5
        q = np.where(pin, np.where(rng.random(q.shape) < 0.5, lo, hi), q)
        for c in robot.limits.coupled:
            rows = rng.random(k) < 0.5
            nz = np.flatnonzero(c.coefficients)
            for r in np.flatnonzero(rows):
                bound = c.lower if rng.random() < 0.5 else c.upper
                if not math.isfinite(bound):
                    continue
                j = int(rng.choice(nz))
                q[r, j] += (bound - float(c.coefficients @ q[r])) / c.coefficients[j]
        q = q[robot.limits.contains_batch(q)]
        out.extend(r for r in q if not clear or is_clear(robot, r))
    return np.array(out[:m])


def fk_agreement(robot: Any, peer_fk: Any, indices: NDArray[np.int64], m: int = 500, seed: int = 12345) -> float:
    """Largest distance [m] between the peer's tool point and ``robot.fk`` at ``m`` random configs."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for q in random_configs(robot, m, rng):
        worst = max(worst, float(np.linalg.norm(peer_fk(q[indices]) - robot.fk(q))))
    return worst


class Adapter:
    """Base class: one solver bound to one arm."""

    name = "?"
    #: where the peer's model came from (``robot.urdf`` or ``robot.geometry``)
    source = ""
    #: largest FK disagreement with robot.fk found [m]; None for armd (it is robot.fk)
    fk_error: float | None = None

    def __init__(self, robot: Any, tolerance: float) -> None:
        self.robot = robot
        self.tolerance = tolerance
        self.indices = np.arange(robot.nq)

    def prepare(self, target: FloatArray) -> Any:
        return target

    def call(self, prepared: Any, seed: FloatArray) -> Any:
        raise NotImplementedError

    def answer(self, raw: Any, seed: FloatArray) -> Answer:
        raise NotImplementedError

    def _full(self, q_peer: FloatArray, seed: FloatArray) -> FloatArray:
        """The peer's joints in armd's joint vector; joints it does not model stay at the seed."""
        q = np.array(seed, dtype=np.float64)
        q[self.indices] = q_peer
        return q

    def _check_fk(self) -> None:
        self.fk_error = fk_agreement(self.robot, self.peer_fk, self.indices)
        if not self.fk_error <= FK_AGREEMENT:
            raise Unavailable(
                f"{self.name} FK differs from robot.fk by {self.fk_error:.3g} m on {self.robot.name} "
                f"(model from {self.source})"
            )

    def peer_fk(self, q_peer: FloatArray) -> FloatArray:
        raise NotImplementedError


# -- armd ---------------------------------------------------------------------------------


class Armd(Adapter):
    """armd's ``solvers.solve_ik(robot, target, seed=...)``, position only (``approach=None``)."""

    name = "armd"
    source = "robot (Pinocchio, exact model)"

    def __init__(self, robot: Any, tolerance: float) -> None:
        super().__init__(robot, tolerance)
        try:
            from armd.solvers import solve_ik
        except Exception as e:  # ImportError while it is being written, or a broken module
            raise Unavailable(f"armd: `from solvers import solve_ik` failed: {type(e).__name__}: {e}") from None
        self._solve = solve_ik

    def call(self, prepared: Any, seed: FloatArray) -> Any:
        # the benchmark's tolerance, as rtb is given it (armd's default is 1e-9 m)
        return self._solve(self.robot, prepared, seed=seed, tolerance=self.tolerance)

    def answer(self, raw: Any, seed: FloatArray) -> Answer:
        q = None if raw.q is None else np.asarray(raw.q, dtype=np.float64)
        return Answer(q=q, claimed=raw.status == "ok", status=str(raw.status), reported_error=float(raw.position_error))


def armd_batch(robot: Any) -> Any:
    """``solvers.solve_ik_batch`` if armd has it, else None."""
    try:
        from armd import solvers
    except Exception:
        return None
    return getattr(solvers, "solve_ik_batch", None)


# -- roboticstoolbox-python ----------------------------------------------------------------


def rtb_tolerance(position_tolerance: float) -> float:
    """ik_LM's ``tol`` for a position tolerance [m].

    ik_LM stops when ``E = 0.5 e^T We e < tol`` (``ets/cpp-extensions/ik.cpp``), so with the
    mask ``[1, 1, 1, 0, 0, 0]`` it stops when ``|e| < sqrt(2 tol)``. Its default
    ``tol=1e-6`` would accept a position error up to 1.4 mm.
    """
    return 0.5 * position_tolerance**2


class Rtb(Adapter):
    """roboticstoolbox-python's C++ ``ik_LM`` on the arm's ETS."""

    name = "rtb"

    def __init__(self, robot: Any, tolerance: float) -> None:
        super().__init__(robot, tolerance)
        try:
            import roboticstoolbox as rtb
            from spatialmath import SE3
        except Exception as e:
            raise Unavailable(f"rtb: import roboticstoolbox failed: {type(e).__name__}: {e}") from None
        self._SE3 = SE3
        ets = self._from_urdf(rtb) if not has_mimic_joints(robot) else None
        self.ets: Any = ets if ets is not None else self._from_chain(geometry_chain(robot))
        # The same box limits as armd uses (robot.toml may override the URDF's <limit>).
        self.ets.qlim = np.vstack([robot.limits.lower[self.indices], robot.limits.upper[self.indices]])
        self.mask = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
        self.tol = rtb_tolerance(tolerance)
        self._check_fk()

    def _from_urdf(self, rtb: Any) -> Any:
        from roboticstoolbox.models.URDF.URDFRobot import URDF_read

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            elinks, name, _ = URDF_read(str(self.robot.folder / "robot.urdf"))
            model = rtb.Robot(elinks, name=name)
            ets = model.ets(start=self.robot.base_frame, end=self.robot.tool_frame)
        if ets.n != self.robot.nq:
            return None
        self.source = "robot.urdf"
        return ets

    def _from_chain(self, chain: EquivalentChain) -> Any:
        from roboticstoolbox import ET

        self.source = chain.source
        self.indices = chain.indices
        ets: Any = None
        for k, j in enumerate(chain.joints):
            parts = [ET.SE3(self._SE3.Trans(*j.origin))] if any(j.origin) else []
            axis = np.array(j.axis)
            a = int(np.argmax(np.abs(axis)))
            if not (abs(abs(axis[a]) - 1.0) < 1e-12 and np.count_nonzero(axis) == 1):
                raise Unavailable(f"rtb: joint axis {j.axis} is not a coordinate axis")
            flip = bool(axis[a] < 0)
            parts.append((ET.Rx, ET.Ry, ET.Rz)[a](jindex=k, flip=flip))
            for p in parts:
                ets = p if ets is None else ets * p
        if any(chain.tip):
            ets = ets * ET.SE3(self._SE3.Trans(*chain.tip))
        return ets

    def peer_fk(self, q_peer: FloatArray) -> FloatArray:
        return np.asarray(self.ets.fkine(q_peer).t, dtype=np.float64)

    def prepare(self, target: FloatArray) -> Any:
        return self._SE3.Trans(*target)

    def call(self, prepared: Any, seed: FloatArray) -> Any:
        return self.ets.ik_LM(prepared, q0=seed[self.indices], mask=self.mask, tol=self.tol)

    def answer(self, raw: Any, seed: FloatArray) -> Answer:
        return Answer(q=self._full(np.asarray(raw.q, dtype=np.float64), seed), claimed=bool(raw.success))


# -- ikpy ---------------------------------------------------------------------------------------


class Ikpy(Adapter):
    """ikpy's ``Chain.inverse_kinematics(target_position)``, position only."""

    name = "ikpy"
    #: ``tol`` handed to ikpy (SciPy least_squares ftol and xtol); None keeps ikpy's default.
    #: 1e-10 and 1e-12 gave the same success rates at 1e-6 m, only slower.
    IKPY_TOL: float | None = None

    def __init__(self, robot: Any, tolerance: float) -> None:
        super().__init__(robot, tolerance)
        try:
            import ikpy.chain
            import ikpy.link  # noqa: F401
        except Exception as e:
            raise Unavailable(f"ikpy: import failed: {type(e).__name__}: {e}") from None
        chain = self._from_urdf() if not has_mimic_joints(robot) else None
        self.chain: Any = chain if chain is not None else self._from_chain(geometry_chain(robot))
        self._kwargs = {} if self.IKPY_TOL is None else {"tol": self.IKPY_TOL}
        for i, k in zip(self.active, self.indices, strict=True):
            self.chain.links[i].bounds = (float(robot.limits.lower[k]), float(robot.limits.upper[k]))
        self._check_fk()

    def _from_urdf(self) -> Any:
        import ikpy.chain

        path = str(self.robot.folder / "robot.urdf")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            probe = ikpy.chain.Chain.from_urdf_file(path, base_elements=[self.robot.base_frame])
            mask = [link.name in self.robot.joint_names for link in probe.links]
            chain = ikpy.chain.Chain.from_urdf_file(path, base_elements=[self.robot.base_frame], active_links_mask=mask)
        names = [link.name for link in chain.links]
        if [n for n in names if n in self.robot.joint_names] != list(self.robot.joint_names):
            return None
        self.active = [names.index(j) for j in self.robot.joint_names]
        self.source = "robot.urdf"
        return chain

    def _from_chain(self, chain: EquivalentChain) -> Any:
        import ikpy.chain
        from ikpy.link import OriginLink, URDFLink

        links: list[Any] = [OriginLink()]
        for j in chain.joints:
            links.append(
                URDFLink(
                    name=self.robot.joint_names[j.index],
                    origin_translation=np.array(j.origin),
                    origin_orientation=np.zeros(3),
                    rotation=np.array(j.axis),
                    joint_type="revolute",
                )
            )
        links.append(
            URDFLink(
                name="tip", origin_translation=np.array(chain.tip), origin_orientation=np.zeros(3), joint_type="fixed"
            )
        )
        mask = [False] + [True] * len(chain.joints) + [False]
        self.active = list(range(1, len(chain.joints) + 1))
        self.indices = chain.indices
        self.source = chain.source
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return ikpy.chain.Chain(links, active_links_mask=mask, name=self.robot.name)

    def _chain_vector(self, q_peer: FloatArray) -> FloatArray:
        full = np.zeros(len(self.chain.links))
        full[self.active] = q_peer
        return full

    def peer_fk(self, q_peer: FloatArray) -> FloatArray:
        return np.asarray(self.chain.forward_kinematics(self._chain_vector(q_peer))[:3, 3], dtype=np.float64)

    def call(self, prepared: Any, seed: FloatArray) -> Any:
        return self.chain.inverse_kinematics(
            prepared, initial_position=self._chain_vector(seed[self.indices]), **self._kwargs
        )

    def answer(self, raw: Any, seed: FloatArray) -> Answer:
        return Answer(q=self._full(np.asarray(raw, dtype=np.float64)[self.active], seed))


SOLVERS: dict[str, type[Adapter]] = {"armd": Armd, "rtb": Rtb, "ikpy": Ikpy}


def versions() -> dict[str, str]:
    """Versions of everything whose speed or answers the numbers depend on."""
    import platform
    import sys
    from importlib import metadata

    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for dist in ("numpy", "scipy", "pin", "roboticstoolbox-python", "spatialmath-python", "ikpy", "armd"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    out["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import os

    out["cores"] = str(os.cpu_count())
    return out


def reach_bound(robot: Any) -> float:
    """An upper bound [m] on the tool point's distance from the base origin.

    The sum of the lengths of every fixed translation on the path from the base to the tool
    frame in ``robot.model``: rotations do not change lengths, so no configuration reaches
    farther. Points beyond it are unreachable whatever the joint limits.
    """
    model = robot.model
    frame = model.frames[robot.tool_frame_id]
    total = float(np.linalg.norm(frame.placement.translation))
    for j in model.supports[frame.parentJoint]:
        total += float(np.linalg.norm(model.jointPlacements[j].translation))
    return total


def unit_vectors(m: int, rng: np.random.Generator) -> FloatArray:
    v = rng.normal(size=(m, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


__all__ = [
    "FK_AGREEMENT",
    "SOLVERS",
    "Adapter",
    "Answer",
    "Armd",
    "EquivalentChain",
    "Ikpy",
    "Rtb",
    "Unavailable",
    "armd_batch",
    "configs_at_limits",
    "fk_agreement",
    "geometry_chain",
    "has_mimic_joints",
    "is_clear",
    "random_configs",
    "reach_bound",
    "rtb_tolerance",
    "unit_vectors",
    "versions",
]
