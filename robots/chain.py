"""Recognising the closed-form family in a URDF's kinematic chain.

From the joints that carry the tool frame (base to tool) alone, :func:`recognise` looks for
the family of :mod:`robots.geometry`: a yaw joint about the vertical (+z or -z, anywhere in
the base's plane), then two or three pitch joints whose axes are horizontal and parallel
(the arm's plane), then optionally a wrist roll (any other axis). It measures, at the URDF's
zero, every number the closed form needs: each joint's sign and zero (the family's angles are
the URDF's mapped, so that armd's joint angles stay the vendor's), the yaw axis's place, the
shoulder pivot, the link lengths, the lateral offset of the tool from the yaw axis, the tool
pitch's offset, and how the roll moves the tool (:class:`~robots.geometry.RollModel`). Then it
checks the family's FK against Pinocchio's at random configurations: the closed form is used
only where it is exact (to 1e-9 m). Otherwise it says why not, naming the joint.

All of it is read from Pinocchio's world-frame joint Jacobian at q = 0: for a revolute joint,
the column's angular part is the axis (unit) and its linear part ``p x axis`` for any point p
of the axis.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .frames import frame_id
from .geometry import Geometry, RollModel
from .limits import JointLimits
from .types import FloatArray

PARALLEL = 1e-3  # |sin| between axes that count as parallel (and as vertical, horizontal)
EXACT = 1e-9  # [m] the family's FK matching Pinocchio's to this everywhere is the exact model
NEAR = 1e-3  # [m] ... to this, a seed: the answers are refined on the exact model (a URDF's 1.5708 for pi/2)
_REVOLUTE = {"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned"}


@dataclass(frozen=True)
class Recognised:
    """What :func:`recognise` found: the family's parameters, or why the chain is not of it."""

    geometry: Geometry | None
    reason: str  # a line: "yaw + 3 pitch + roll" or "joint wrist_flex's axis is not parallel to ..."


def _no(reason: str) -> Recognised:
    return Recognised(None, reason)


def recognise(
    model: pin.Model,
    tool_frame: str,
    joint_names: tuple[str, ...],
    limits: JointLimits,
    neutral: FloatArray,
    tool_axis: FloatArray,
) -> Recognised:
    """The family in ``model``'s chain to ``tool_frame`` (the tool axis is ``tool_axis`` in the
    tool frame), or the reason it is not there."""
    fid = frame_id(model, tool_frame)
    chain = []
    j = int(model.frames[fid].parentJoint)
    while j > 0:
        chain.append(j)
        j = int(model.parents[j])
    chain.reverse()
    for j in chain:
        kind = model.joints[j].shortname()
        if kind == "JointModelMimic":
            return _no(
                f"joint {model.names[j]!r} mimics another (a linkage): give its closed form as [geometry] in robot.toml"
            )
        if kind not in _REVOLUTE:
            what = "prismatic" if "Prismatic" in kind or kind.startswith("JointModelP") else kind
            return _no(f"joint {model.names[j]!r} is {what}: the family has revolute joints only")
    if not 3 <= len(chain) <= 5:
        return _no(f"{len(chain)} joints move the tool; the family has 3 to 5 (yaw, 2 or 3 pitch, a roll)")
    index = {name: i for i, name in enumerate(joint_names)}
    names = [model.names[j] for j in chain]
    qi = [index[n] for n in names]

    data = model.createData()
    q0 = np.zeros(model.nq)
    pin.computeJointJacobians(model, data, q0)
    placement = pin.updateFramePlacement(model, data, fid)
    axes, points = [], []
    for j in chain:
        col = np.array(data.J[:, model.joints[j].idx_v])
        axis = col[3:] / np.linalg.norm(col[3:])
        axes.append(axis)
        points.append(np.cross(axis, col[:3]))
    tool = np.array(placement.translation)
    tool_dir = np.array(placement.rotation) @ tool_axis

    yaw_axis = axes[0]
    if math.hypot(yaw_axis[0], yaw_axis[1]) > PARALLEL:
        return _no(f"the first joint, {names[0]!r}, does not turn about the vertical (its axis is {_fmt(yaw_axis)})")
    lateral = axes[1]
    if abs(lateral[2]) > PARALLEL:
        return _no(f"joint {names[1]!r}'s axis is not horizontal at the URDF's zero ({_fmt(lateral)}): not a pitch")
    pitches = 1
    while pitches + 1 < len(chain) and np.linalg.norm(np.cross(axes[pitches + 1], lateral)) <= PARALLEL:
        pitches += 1
    if pitches < 2:
        return _no(
            f"joint {names[2]!r}'s axis is not parallel to {names[1]!r}'s: one pitch joint, the family needs 2 or 3"
        )
    if pitches > 3:
        return _no(f"{pitches} parallel pitch joints from {names[1]!r}: the family has 2 or 3")
    rest = len(chain) - 1 - pitches
    if rest > 1:
        return _no(
            f"joint {names[pitches + 2]!r} follows the wrist roll {names[pitches + 1]!r}: the family ends at the roll"
        )
    roll_j = pitches + 1 if rest == 1 else None

    # the yaw frame at q = 0: u outward, v = z x u lateral; the arm's outward side is where the
    # tool is at the neutral pose
    h = math.hypot(lateral[0], lateral[1])
    v0: FloatArray = np.array([lateral[0] / h, lateral[1] / h, 0.0])
    u0: FloatArray = np.array([v0[1], -v0[0], 0.0])  # v0 x z
    base = np.array(points[0][:2], dtype=np.float64)
    if _outward(model, fid, neutral, chain, u0, base, v0) < 0.0:
        u0, v0 = -u0, -v0

    def plane(p: FloatArray) -> FloatArray:  # (u, v, z) in the yaw frame at q = 0
        d = p - np.array([base[0], base[1], 0.0])
        return np.array([d @ u0, d @ v0, p[2]])

    pts = [plane(points[k]) for k in range(1, pitches + 1)]
    tip = plane(tool)
    links = [pts[k + 1] - pts[k] for k in range(pitches - 1)] + [tip - pts[-1]]
    lengths = [math.hypot(link[0], link[2]) for link in links]
    for k, length in enumerate(lengths):
        if length < 1e-6:
            return _no(f"the link after joint {names[k + 1]!r} has no length in the arm's plane")
    angles = [math.atan2(link[2], link[0]) for link in links]
    sign = [1.0 if yaw_axis[2] > 0 else -1.0] + [(-1.0 if axes[k] @ v0 > 0 else 1.0) for k in range(1, pitches + 1)]
    zero = [math.atan2(u0[1], u0[0]), angles[0]] + [angles[k] - angles[k - 1] for k in range(1, pitches)]
    tool_plane = np.array([tool_dir @ u0, tool_dir @ v0, tool_dir[2]])
    pitch_offset = math.atan2(tool_plane[2], tool_plane[0]) - angles[-1]

    roll_model = None
    roll_index = None
    if roll_j is not None:
        d = np.array([axes[roll_j] @ u0, axes[roll_j] @ v0, axes[roll_j][2]])
        a = plane(points[roll_j]) - np.array([pts[-1][0], 0.0, pts[-1][2]])
        w = tip - plane(points[roll_j])
        off_axis = np.linalg.norm(w - d * (w @ d))
        skew = np.linalg.norm(np.cross(tool_plane, d))
        if off_axis > 1e-12 or skew > 1e-12:  # the roll moves the tool point or turns the tool axis
            roll_model = RollModel(_vec(a), _vec(d), _vec(w), _vec(tool_plane))
            roll_index = qi[roll_j]

    geometry = Geometry(
        yaw=qi[0],
        shoulder=qi[1],
        elbow=qi[2],
        wrist=qi[3] if pitches == 3 else None,
        pivot=(float(pts[0][0]), float(tip[1]), float(pts[0][2])),
        upper_arm=lengths[0],
        forearm=lengths[1],
        hand=lengths[2] if pitches == 3 else 0.0,
        tool_offset=(0.0, 0.0),
        level=False,
        sign=tuple(sign + [1.0] * (4 - len(sign))),  # type: ignore[arg-type]
        zero=tuple(zero + [0.0] * (4 - len(zero))),  # type: ignore[arg-type]
        base=(float(base[0]), float(base[1])),
        pitch_offset=pitch_offset,
        roll=roll_index,
        roll_model=roll_model,
        source="found from the URDF's chain",
    )
    worst = _worst_mismatch(model, fid, geometry, limits)
    if worst > NEAR:
        return _no(
            f"the chain has the family's joints but its FK differs from the family's by {worst:.3g} m "
            "(a case armd does not recognise yet: give [geometry] in robot.toml)"
        )
    if worst > EXACT:  # nearly: axes a hair off parallel or vertical (rounded angles in the URDF)
        geometry = dataclasses.replace(
            geometry,
            source=f"found from the URDF's chain to {worst:.2g} m, each answer refined on the exact model",
        )
    shape = f"yaw + {pitches} pitch" + (" + roll" if roll_j is not None else "")
    return Recognised(geometry, shape)


@dataclass(frozen=True)
class RollJoint:
    """A wrist roll about the tool axis: the tool's roll (:meth:`Robot.tool_roll`) is
    ``sign q[index] + offset`` [rad]."""

    index: int
    sign: float
    offset: float


def roll_joint(
    model: pin.Model, tool_frame: str, joint_names: tuple[str, ...], geometry: Geometry, tool_axis: FloatArray
) -> RollJoint | None:
    """The last joint of the chain to the tool when it is outside the family and turns about the
    tool axis (to 1e-6): the arm's wrist roll, with its sign and offset (measured at q = 0)."""
    fid = frame_id(model, tool_frame)
    j = int(model.frames[fid].parentJoint)
    if j <= 0 or model.joints[j].shortname() not in _REVOLUTE:
        return None
    index = list(joint_names).index(model.names[j]) if model.names[j] in joint_names else -1
    if index < 0 or index in geometry.joints:
        return None
    data = model.createData()
    q0 = np.zeros(model.nq)
    pin.computeJointJacobians(model, data, q0)
    col = np.array(data.J[:, model.joints[j].idx_v])
    axis = col[3:] / np.linalg.norm(col[3:])
    rotation = np.array(pin.updateFramePlacement(model, data, fid).rotation)
    d = rotation @ tool_axis
    if np.linalg.norm(np.cross(axis, d)) > 1e-6:
        return None
    return RollJoint(index, 1.0 if axis @ d > 0 else -1.0, tool_roll(geometry, q0, rotation, tool_axis))


def tool_roll(geometry: Geometry, q: FloatArray, rotation: FloatArray, tool_axis: FloatArray) -> float:
    """The tool's roll [rad] about its axis at ``q`` (tool frame ``rotation`` in base): the angle,
    about the tool axis, from the arm's vertical plane (the direction in it perpendicular to the
    tool axis and upward) to the tool frame's z axis (its x axis where z is the tool axis)."""
    d = rotation @ tool_axis
    ref = rotation[:, 0] if abs(tool_axis[2]) > 0.5 else rotation[:, 2]
    h = geometry.heading(q)
    f = np.array([math.cos(h), math.sin(h), 0.0])
    pitch = math.atan2(d[2], d @ f)
    up = -math.sin(pitch) * f + math.cos(pitch) * np.array([0.0, 0.0, 1.0])
    return math.atan2(float(np.cross(up, ref) @ d), float(up @ ref))


def _outward(
    model: pin.Model, fid: int, neutral: FloatArray, chain: list[int], u0: FloatArray, base: FloatArray, v0: FloatArray
) -> float:
    """How far out along ``u0`` the tool is at the neutral pose, the yaw turned back to 0 (the
    tool, else the farthest joint out, decides)."""
    data = model.createData()
    q = neutral.copy()
    q[model.joints[chain[0]].idx_q] = 0.0
    pin.forwardKinematics(model, data, q)
    tool = np.array(pin.updateFramePlacement(model, data, fid).translation)
    for p in [tool] + [np.array(data.oMi[j].translation) for j in reversed(chain[1:])]:
        out = float((p[:2] - base) @ u0[:2])
        if abs(out) > 1e-6:
            return out
    return 1.0


def _worst_mismatch(model: pin.Model, fid: int, geometry: Geometry, limits: JointLimits) -> float:
    rng = np.random.default_rng(20261202)
    data = model.createData()
    worst = 0.0
    for _ in range(64):
        q = rng.uniform(limits.lower, limits.upper)
        pin.forwardKinematics(model, data, q)
        p = np.array(pin.updateFramePlacement(model, data, fid).translation)
        worst = max(worst, float(np.linalg.norm(p - geometry.fk(q))))
    return worst


def _vec(v: FloatArray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _fmt(v: FloatArray) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"
