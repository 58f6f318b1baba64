"""The :class:`Robot`: one arm's model, limits, actuators and forward kinematics.

A Robot is built once at start-up by :mod:`robots.catalogue` from a folder holding
``robot.urdf`` and ``robot.toml``, and is read-only afterwards, so threads may share it:
the Pinocchio ``Data`` that FK writes into is kept per thread.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from armd.errors import BadRequest

from .actuators import ActuatorMap, Gripper
from .angles import wrap
from .chain import RollJoint
from .collision import CollisionModel
from .frames import frame_id
from .geometry import Geometry
from .limits import JointLimits
from .sensors import RangeSensor
from .types import FloatArray

_FLOAT64 = np.dtype(np.float64)  # native float64: ``is`` against it is the quick check (not another byte order)


@dataclass(frozen=True)
class ToolPose:
    """Tool point [m] in ``base`` and tool pitch [rad] (angle of the tool axis to the horizontal)."""

    position: FloatArray
    pitch: float


class Robot:
    """One arm of the catalogue (or of a user's folder).

    Attributes:
        name: catalogue name (the folder's name).
        joint_names: URDF joint names, in the order of the joint vector ``q``.
        limits: position (box and coupled), velocity, acceleration and jerk limits.
        actuators: the actuator map ``a = M q + b`` and each actuator's command units.
        gripper: the gripper actuator, if any.
        geometry: parameters of the closed-form solver's family, if the arm belongs to it
            (found from the chain, or robot.toml's ``[geometry]``).
        family_note: how the arm's chain was read: its shape ("yaw + 3 pitch + roll"), or why
            it is not of the family.
        tool_axis: the tool axis in the tool frame (unit; +x unless robot.toml names another).
        roll_joint: the wrist roll about the tool axis of a closed-form arm, if it has one: what
            ``roll`` in an IK request turns.
        sensors: range sensors by name.
        neutral: the rest configuration [rad].
        model: the Pinocchio model built from ``robot.urdf`` (mimic joints resolved).
        collision: the arm's collision shapes and world, or None: not checked, because
            ``collision_off`` (robot.toml's ``[collision] meshes_optional = true`` and shapes
            that Pinocchio or coal cannot load).
        collision_links: what robot.toml changed of single links' collision shapes (a
            stand-in, a skip) or why a link's mesh was left out: link name -> what is said in
            ``info`` (robots/stand_ins.py).
    """

    def __init__(
        self,
        *,
        name: str,
        title: str,
        folder: Path,
        model: pin.Model,
        tool_frame: str,
        base_frame: str,
        joint_names: tuple[str, ...],
        limits: JointLimits,
        actuators: ActuatorMap,
        gripper: Gripper | None,
        geometry: Geometry | None,
        sensors: dict[str, RangeSensor],
        neutral: FloatArray,
        controller: dict[str, object],
        family_note: str = "",
        tool_axis: FloatArray | None = None,
        roll_joint: RollJoint | None = None,
        collision: CollisionModel | None = None,
        collision_off: str | None = None,
        collision_links: dict[str, str] | None = None,
        tracking_tolerance: FloatArray | None = None,
    ) -> None:
        self.name = name
        self.title = title
        self.folder = folder
        self.model = model
        self.tool_frame = tool_frame
        self.base_frame = base_frame
        self.tool_frame_id = frame_id(model, tool_frame)
        self.joint_names = joint_names
        self.limits = limits
        self.actuators = actuators
        self.gripper = gripper
        self.geometry = geometry
        self.sensors = sensors
        self.neutral = neutral
        self.controller = controller
        self.family_note = family_note
        self.roll_joint = roll_joint
        self.collision = collision
        # why collisions are not checked (robot.toml's [collision] meshes_optional, a mesh that cannot be used)
        self.collision_off = collision_off
        self.collision_links = dict(collision_links or {})
        # [rad] per joint: the most a measured position may trail the plan (execution monitoring)
        self.tracking_tolerance = (
            np.full(len(joint_names), 0.15) if tracking_tolerance is None else np.asarray(tracking_tolerance, float)
        )
        self.tool_axis = np.array([1.0, 0.0, 0.0]) if tool_axis is None else np.asarray(tool_axis, dtype=float)
        # state the layers above derive from the arm, made once and kept with it (the solver's arrays)
        self.derived: dict[str, object] = {}
        self._local = threading.local()

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, joints={list(self.joint_names)})"

    @property
    def nq(self) -> int:
        return len(self.joint_names)

    @property
    def chooses_pitch(self) -> bool:
        """Whether the arm can choose its tool pitch at a point: a wrist pitch joint in its closed
        form, or (outside the family) four or more joints moving the tool."""
        if self.geometry is not None:
            return self.geometry.has_wrist
        count = 0
        j = int(self.model.frames[self.tool_frame_id].parentJoint)
        while j > 0:
            count += self.model.joints[j].nq
            j = int(self.model.parents[j])
        return count >= 4

    # -- input checking ----------------------------------------------------------------

    def joint_vector(self, q: object, field: str = "q") -> FloatArray:
        """``q`` as a float array of this arm's length, all finite; else :class:`BadRequest`."""
        if type(q) is np.ndarray and q.dtype is _FLOAT64 and q.shape == (self.nq,):
            flags = q.flags
            if flags.c_contiguous and flags.writeable and math.isfinite(sum(q.tolist())):
                return q  # the common case: already a finite vector of the right length
        try:
            # a contiguous, writable copy: compiled code sees one array type (a view of a broadcast
            # array is read-only, another type, and would be compiled anew, for seconds)
            arr = np.array(q, dtype=float)
        except (TypeError, ValueError):
            raise BadRequest(f"{field} must be a list of {self.nq} numbers [rad]", field=field) from None
        if arr.shape != (self.nq,):
            raise BadRequest(
                f"{field} must have {self.nq} values ({', '.join(self.joint_names)}), got shape {list(arr.shape)}",
                field=field,
            )
        if not np.all(np.isfinite(arr)):
            raise BadRequest(f"{field} must be finite numbers, got {arr.tolist()}", field=field)
        return arr

    # -- kinematics ----------------------------------------------------------------------

    def data(self) -> pin.Data:
        """This thread's Pinocchio ``Data`` for :attr:`model` (Data is written by every
        computation, so each thread gets its own; reuse it within a thread)."""
        data = getattr(self._local, "data", None)
        if data is None:
            data = self.model.createData()
            self._local.data = data
        return data

    def _tool_placement(self, q: FloatArray) -> pin.SE3:
        data = self.data()
        pin.forwardKinematics(self.model, data, q)
        return pin.updateFramePlacement(self.model, data, self.tool_frame_id)

    def fk(self, q: Sequence[float] | FloatArray) -> FloatArray:
        """Tool point [m] in ``base`` for joint vector ``q`` [rad] (Pinocchio, exact model)."""
        return np.array(self._tool_placement(np.asarray(q, dtype=float)).translation)

    def pose(self, q: Sequence[float] | FloatArray) -> ToolPose:
        """Tool point [m] and tool pitch [rad] for ``q``."""
        qa = np.asarray(q, dtype=float)
        placement = self._tool_placement(qa)
        return ToolPose(np.array(placement.translation), self._pitch(qa, placement.rotation))

    def tool_pitch(self, q: Sequence[float] | FloatArray) -> float:
        """Angle [rad] of the tool axis (:attr:`tool_axis`) to the horizontal, in [-pi, pi).

        Measured in the arm's vertical plane (forward is the yaw direction), so a tool
        pointing back and down has a pitch beyond -pi/2. 0 is level ("parallel"), -pi/2
        points straight down ("perpendicular").
        """
        qa = np.asarray(q, dtype=float)
        return self._pitch(qa, self._tool_placement(qa).rotation)

    def _pitch(self, q: FloatArray, rotation: FloatArray) -> float:
        d = rotation @ self.tool_axis
        if self.geometry is None:
            return wrap(math.atan2(d[2], math.hypot(d[0], d[1])))
        heading = self.geometry.heading(q)
        return wrap(math.atan2(d[2], d[0] * math.cos(heading) + d[1] * math.sin(heading)))

    def tool_roll(self, q: Sequence[float] | FloatArray) -> float | None:
        """The tool's roll [rad] about its axis, in [-pi, pi) (None: no wrist roll): 0 when the tool
        frame's z axis (x where z is the tool axis) lies in the arm's vertical plane, upward;
        positive turning about the tool axis. ``sign q[roll] + offset``: the pitch and the yaw
        do not change it."""
        rj = self.roll_joint
        if rj is None:
            return None
        return wrap(rj.sign * float(q[rj.index]) + rj.offset)

    def roll_angle(self, roll: float, seed: FloatArray) -> float:
        """The wrist roll joint's angle [rad] for the tool roll ``roll``, within its limits
        (the turn nearest ``seed``'s); :class:`BadRequest` when the arm has no roll or the joint
        cannot reach it."""
        rj = self.roll_joint
        if rj is None:
            raise BadRequest(f"{self.name} has no wrist roll about its tool axis: roll cannot be asked", field="roll")
        if isinstance(roll, bool) or not isinstance(roll, (int, float)) or not -math.pi <= roll <= math.pi:
            raise BadRequest(f"roll must be a number in [-pi, pi] rad, got {roll!r}", field="roll")
        value = rj.sign * (roll - rj.offset)
        lo, hi = float(self.limits.lower[rj.index]), float(self.limits.upper[rj.index])
        turns = [value + 2.0 * math.pi * k for k in range(-3, 4)]
        inside = [v for v in turns if lo - 1e-12 <= v <= hi + 1e-12]
        if not inside:
            name = self.joint_names[rj.index]
            raise BadRequest(
                f"roll {roll:.4f} rad needs joint {name!r} at {wrap(value):.4f} rad, outside its limits "
                f"[{lo:.4f}, {hi:.4f}]",
                field="roll",
            )
        best = min(inside, key=lambda v: abs(v - float(seed[rj.index])))
        return min(max(best, lo), hi)

    def jacobian(self, q: Sequence[float] | FloatArray) -> FloatArray:
        """Jacobian of the tool point [m/rad], shape (3, nq), in ``base`` axes."""
        qa = np.asarray(q, dtype=float)
        data = self.data()
        J = pin.computeFrameJacobian(self.model, data, qa, self.tool_frame_id, pin.LOCAL_WORLD_ALIGNED)
        return np.array(J[:3, :])

    def frame_position(self, q: Sequence[float] | FloatArray, frame: str) -> FloatArray:
        """Origin [m] of any URDF frame, in ``base``."""
        fid = frame_id(self.model, frame)
        if fid >= self.model.nframes:
            frames = sorted({f.name for f in self.model.frames})
            raise BadRequest(f"unknown frame {frame!r}; frames: {', '.join(frames)}", field="frame")
        data = self.data()
        pin.forwardKinematics(self.model, data, np.asarray(q, dtype=float))
        return np.array(pin.updateFramePlacement(self.model, data, fid).translation)

    def skeleton(self, q: Sequence[float] | FloatArray) -> FloatArray:
        """The arm as a stick figure: the base origin, the origin of every joint that moves
        the tool, then the tool point; (k, 3) [m] in ``base``, repeated points dropped.
        For drawings (workspace maps)."""
        qa = np.asarray(q, dtype=float)
        data = self.data()
        pin.forwardKinematics(self.model, data, qa)
        chain = []
        j = int(self.model.frames[self.tool_frame_id].parentJoint)
        while j > 0:
            chain.append(j)
            j = int(self.model.parents[j])
        points = [np.zeros(3)] + [np.array(data.oMi[j].translation) for j in reversed(chain)]
        points.append(np.array(pin.updateFramePlacement(self.model, data, self.tool_frame_id).translation))
        kept = [points[0]]
        for point in points[1:]:  # joints that share an origin (yaw and shoulder, say) are one point
            if np.linalg.norm(point - kept[-1]) > 1e-9:
                kept.append(point)
        return np.array(kept)

    # -- sensors ----------------------------------------------------------------------

    def sensor_point(
        self, sensor: str, distance: float, bearing: float = 0.0, q: FloatArray | None = None
    ) -> FloatArray:
        """The base-frame point [m] that a range-sensor reading sees.

        Scanner sensors use (``distance`` [m], ``bearing`` [rad]); a sensor on an arm frame
        looks along that frame's +x and needs the joint vector ``q``.
        """
        s = self._sensor(sensor)
        if s.mount == "scanner":
            return s.scanner_point(distance, bearing)
        d = s.check_range(distance)
        origin, direction = self.sensor_ray(sensor, bearing, q)
        return origin + d * direction

    def sensor_ray(
        self, sensor: str, bearing: float = 0.0, q: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Where a range sensor looks from and along (a unit vector), in the base frame: a scanner
        from its ``position`` at ``bearing`` [rad] in the horizontal plane; a sensor on an arm
        frame along that frame's +x, at the joint vector ``q``."""
        s = self._sensor(sensor)
        if s.mount == "scanner":
            assert s.position is not None
            return np.array(s.position, dtype=float), np.array([math.cos(bearing), math.sin(bearing), 0.0])
        if q is None:
            raise BadRequest(
                f"sensor {sensor!r} is on frame {s.frame!r}: its reading is converted at the arm's pose when it "
                "was taken; give that joint vector (seed)",
                field="seed",
            )
        qa = self.joint_vector(q)
        assert s.frame is not None
        fid = frame_id(self.model, s.frame)
        data = self.data()
        pin.forwardKinematics(self.model, data, qa)
        placement = pin.updateFramePlacement(self.model, data, fid)
        return np.array(placement.translation), np.array(placement.rotation[:, 0])

    def _sensor(self, sensor: str) -> RangeSensor:
        if sensor not in self.sensors:
            raise BadRequest(
                f"unknown sensor {sensor!r} on {self.name}; sensors: {', '.join(sorted(self.sensors)) or '(none)'}",
                field="sensor",
            )
        return self.sensors[sensor]

    # -- description -----------------------------------------------------------------------

    @property
    def solver(self) -> str:
        """Which IK this arm gets, and why, in a line (``armd catalogue``, the ``info`` reply)."""
        g = self.geometry
        if g is None:
            return f"numerical: {self.family_note}"
        held = ", the tool held level by a linkage" if g.level else ""
        return f"closed form: {self.family_note} ({g.source}{held})"

    def _linkage(self, k: int) -> dict[str, object]:
        """Actuator ``k``'s linkage for :meth:`describe` (its row is then the slope at mid-range)."""
        link = self.actuators.linkages.get(k)
        if link is None:
            return {}
        return {
            "linkage": {
                **link.describe(),
                "input": self.joint_names[link.input],
                "driven": self.joint_names[link.driven],
            }
        }

    def describe(self) -> dict[str, object]:
        """A JSON-ready summary: joints, limits, actuators, sensors (the protocol's ``info``)."""
        lim = self.limits
        return {
            "name": self.name,
            "title": self.title,
            "solver": self.solver,
            "joints": [
                {
                    "name": n,
                    "lower": float(lim.lower[i]),
                    "upper": float(lim.upper[i]),
                    "velocity": float(lim.velocity[i]),
                    "acceleration": float(lim.acceleration[i]),
                    "jerk": float(lim.jerk[i]),
                }
                for i, n in enumerate(self.joint_names)
            ],
            "coupled_limits": [
                {"name": c.name, "coefficients": c.coefficients.tolist(), "lower": c.lower, "upper": c.upper}
                for c in lim.coupled
            ],
            "actuators": [
                {
                    "name": a.name,
                    "kind": a.kind,
                    "unit": a.unit,
                    "row": self.actuators.M[j].tolist(),
                    "offset": float(self.actuators.b[j]),
                    **self._linkage(j),
                }
                for j, a in enumerate(self.actuators.actuators)
            ],
            "sensors": sorted(self.sensors),
            "neutral": self.neutral.tolist(),
            "wrist": self.chooses_pitch,
            "tool_pitch": "level" if self.geometry and self.geometry.level else "joints",
            "world": self.collision.describe() if self.collision is not None else None,
            "collision": {
                "checked": self.collision is not None,
                "off": self.collision_off,
                "links": self.collision_links,
            },
        }
