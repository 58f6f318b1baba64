"""Loading arms from folders: the built-in catalogue and a user's own folder of arms.

An arm is a folder holding ``robot.urdf`` (the kinematic chain, position and velocity
limits) and ``robot.toml`` (what URDF cannot say: acceleration and jerk limits, coupled
limits, the actuator map, the closed-form solver's geometry, sensors). The format is
documented in ``docs/robot-format.md``. Every problem raises :class:`RobotFileError`
naming the file, the field and what is wrong.
"""

from __future__ import annotations

import difflib
import functools
import logging
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from armd.errors import RobotFileError, UnknownRobot

from . import checks
from .actuators import Actuator, ActuatorMap, BusServo, Gripper, Servo, Stepper
from .chain import recognise, roll_joint
from .collision import GROUND, CollisionModel, Obstacle
from .frames import frame_id
from .geometry import Geometry
from .limits import CoupledLimit, JointLimits
from .linkages import FourBar
from .linkages import region as linkage_region
from .robot import Robot
from .sensors import RangeSensor
from .stand_ins import SHAPES, CollisionEdits, StandIn
from .types import FloatArray
from .units import parse_angle

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

CATALOGUE_DIR = Path(__file__).resolve().parent
_MISSING = object()
# Where robot.toml gives no acceleration or jerk limit for a joint (documented in docs/robot-format.md):
ACCELERATION_PER_VELOCITY = 4.0  # [1/s] acceleration = 4 x velocity limit
JERK_PER_ACCELERATION = 10.0  # [1/s] jerk = 10 x acceleration: full speed from rest in 0.35 s
BUS_ID_MAX = 252  # the highest id of a servo on a Feetech or Dynamixel bus (253.. are reserved, 254 broadcast)
# The most a measured position may trail the plan before the move is aborted, where robot.toml's
# [joints.<name>] tracking_tolerance does not say (adapters whose servos report their position)
TRACKING_TOLERANCE = 0.15  # [rad]
CONTINUOUS_RANGE = 2.0 * math.pi  # [rad] a continuous joint's limits, +-, unless robot.toml narrows them
log = logging.getLogger(__name__)


class _Table:
    """A TOML table being read: typed getters that name the field, and no unknown keys."""

    def __init__(self, file: str, data: Any, path: str) -> None:
        self.file = file
        self.path = path
        if not isinstance(data, dict):
            raise RobotFileError(file, path or None, f"must be a table, got {type(data).__name__}")
        self.data: dict[str, Any] = data
        self.used: set[str] = set()

    def field(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str | None, problem: str) -> RobotFileError:
        return RobotFileError(self.file, self.field(key) if key else (self.path or None), problem)

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        self.used.add(key)
        if key not in self.data:
            if default is _MISSING:
                near = difflib.get_close_matches(key, [k for k in self.data if isinstance(k, str)], n=1)
                hint = f" (found {near[0]!r}: a misspelling?)" if near else ""
                raise self.error(key, f"is required{hint}")
            return default
        return self.data[key]

    def string(self, key: str, default: Any = _MISSING) -> str:
        v = self.raw(key, default)
        if not isinstance(v, str) or not v:
            raise self.error(key, f"must be a non-empty string, got {v!r}")
        return v

    def number(self, key: str, default: Any = _MISSING, *, positive: bool = False, angle: bool = False) -> float:
        v = self.raw(key, default)
        try:
            x = parse_angle(v) if angle else _plain_number(v)
        except ValueError as e:
            raise self.error(key, str(e)) from None
        if not math.isfinite(x):
            raise self.error(key, f"must be finite, got {v!r}")
        if positive and x <= 0:
            raise self.error(key, f"must be positive, got {v!r}")
        return x

    def integer(self, key: str, default: Any = _MISSING, *, minimum: int | None = None) -> int:
        v = self.raw(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"must be an integer, got {v!r}")
        if minimum is not None and v < minimum:
            raise self.error(key, f"must be >= {minimum}, got {v}")
        return v

    def vector(self, key: str, length: int, default: Any = _MISSING, *, angle: bool = False) -> list[float]:
        v = self.raw(key, default)
        if not isinstance(v, list) or len(v) != length:
            raise self.error(key, f"must be a list of {length} numbers, got {v!r}")
        out = []
        for i, item in enumerate(v):
            try:
                x = parse_angle(item) if angle else _plain_number(item)
            except ValueError as e:
                raise self.error(f"{key}[{i}]", str(e)) from None
            if not math.isfinite(x):
                raise self.error(f"{key}[{i}]", f"must be finite, got {item!r}")
            out.append(x)
        return out

    def table(self, key: str, default: Any = _MISSING) -> _Table:
        v = self.raw(key, default)
        return _Table(self.file, v, self.field(key))

    def tables(self, key: str) -> list[_Table]:
        v = self.raw(key, [])
        if not isinstance(v, list):
            raise self.error(key, "must be an array of tables ([[" + self.field(key) + "]])")
        return [_Table(self.file, item, f"{self.field(key)}[{i}]") for i, item in enumerate(v)]

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            near = difflib.get_close_matches(str(unknown[0]), sorted(self.used), n=1)
            raise self.error(
                unknown[0],
                (f"unknown key (a misspelling of {near[0]!r}?)" if near else "unknown key")
                + f"; {'this table has' if self.used else 'no keys are expected here'}"
                + (f": {', '.join(sorted(self.used))}" if self.used else ""),
            )


def _plain_number(v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f"expected a number, got {v!r}")
    return float(v)


# -- the catalogue -------------------------------------------------------------------------


def names() -> list[str]:
    """The catalogue's arms, sorted."""
    return sorted(p.parent.name for p in CATALOGUE_DIR.glob("*/robot.toml"))


@functools.cache
def _load_catalogue(name: str) -> Robot:
    return load_folder(CATALOGUE_DIR / name)


def load(name: str) -> Robot:
    """The catalogue arm ``name`` (loaded once, then shared; a Robot is read-only)."""
    if not isinstance(name, str) or name not in names():
        raise UnknownRobot(str(name), names())
    return _load_catalogue(name)


def load_dir(path: str | Path, refused: dict[str, RobotFileError] | None = None) -> dict[str, Robot]:
    """Every arm in a user's folder: its sub-folders holding ``robot.toml``, or the folder itself.

    An arm that does not load raises its :class:`RobotFileError`; given ``refused``, it is put
    there instead (by the arm's name), said once in the log, and the other arms load: one bad
    arm never takes the others down (``armd serve``, ``armd catalogue``)."""
    root = Path(path)
    if not root.is_dir():
        raise RobotFileError(str(root), None, "is not a folder")
    single = (root / "robot.toml").exists()  # (the folder is an arm's)
    folders = [root] if single else sorted(p.parent for p in root.glob("*/robot.toml"))
    if not folders:
        raise RobotFileError(str(root), None, "holds no arm: expected sub-folders with a robot.toml")
    arms = {}
    for folder in folders:
        try:
            arms[folder.name] = load_folder(folder)
        except Exception as e:  # (an error of armd's own, in a bug's case, refuses this arm only)
            if refused is None:
                raise
            error = e if isinstance(e, RobotFileError) else RobotFileError(str(folder), None, f"does not load: {e!r}")
            refused[folder.name] = error
            log.error("%s: arm refused: %s", folder.name, error.message)
    return arms


def load_folder(folder: str | Path) -> Robot:
    """Build a :class:`Robot` from one arm folder (``robot.toml`` + its URDF)."""
    folder = Path(folder)
    toml_path = folder / "robot.toml"
    file = str(toml_path)
    if not toml_path.exists():
        raise RobotFileError(file, None, "not found")
    data = checks.robot_toml(folder)  # (a regular file in the folder, under its cap)
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise RobotFileError(file, None, f"is not valid TOML: {e}") from None
    return _Builder(folder, file, doc).build()


class _Builder:
    def __init__(self, folder: Path, file: str, doc: dict[str, Any]) -> None:
        self.folder = folder
        self.file = file
        self.top = _Table(file, doc, "")
        # [servo]'s us per rad and pulse range (read with the actuators; a scanner's servo takes them too)
        self._servo_defaults: tuple[float, tuple[float, float]] = (1000.0 / (math.pi / 2), (500.0, 2500.0))

    def build(self) -> Robot:
        top = self.top
        meta = top.table("robot")
        title = meta.string("title", folder_title := self.folder.name)
        del folder_title
        meta.raw("seeds", [])
        urdf_name = meta.string("urdf", "robot.urdf")
        base_frame = meta.string("base_frame", "base")
        tool_frame = meta.string("tool_frame", "tool")
        tool_axis = _tool_axis(meta)
        joints_raw = meta.raw("joints")
        if not (isinstance(joints_raw, list) and joints_raw and all(isinstance(j, str) for j in joints_raw)):
            raise meta.error("joints", f"must be a non-empty list of URDF joint names, got {joints_raw!r}")
        joint_names = tuple(joints_raw)
        if len(set(joint_names)) != len(joint_names):
            raise meta.error("joints", "lists a joint twice")

        # the URDF and its meshes, checked before Pinocchio reads them (robots/checks.py)
        self.edits = self._collision_edits(top)
        self.checked = checks.urdf(self.folder, urdf_name, self.file, self.edits)
        model = self._load_urdf(urdf_name, meta)
        held = self._check_joints(model, joint_names, meta, urdf_name)
        if held:
            model = self._load_urdf(urdf_name, meta, held)
        frames = {f.name for f in model.frames}
        for key, frame in (("base_frame", base_frame), ("tool_frame", tool_frame)):
            if frame not in frames:
                raise meta.error(key, f"{urdf_name} has no frame {frame!r}; frames: {', '.join(sorted(frames))}")

        model = self._rooted_at(model, base_frame, meta, urdf_name)
        n = len(joint_names)
        index = {j: i for i, j in enumerate(joint_names)}
        limits, tracking = self._limits(
            model, joint_names, index, top.table("joints", {}), top.tables("coupled_limits"), urdf_name
        )
        checks.check_limits(limits, self.file)
        neutral = np.array(meta.vector("neutral", n, [0.0] * n, angle=True))
        bad = limits.violations(neutral)
        if bad:
            raise meta.error("neutral", f"is outside the limits: {bad[0].message}")
        meta.finish()

        if top.has("geometry"):
            geometry: Geometry | None = self._geometry(top, index, model, tool_frame, limits)
            assert geometry is not None
            family_note = _shape(geometry, n)
        else:
            found = recognise(model, tool_frame, joint_names, limits, neutral, tool_axis)
            geometry, family_note = found.geometry, found.reason
        roll = roll_joint(model, tool_frame, joint_names, geometry, tool_axis) if geometry is not None else None
        collision, collision_off = self._collision(top, model, urdf_name, neutral)
        actuators, gripper = self._actuators(top, index, limits)
        sensors = self._sensors(top, frames, actuators, gripper)
        controller: dict[str, object] = {}
        if top.has("controller"):
            ctl = top.table("controller")
            controller = dict(ctl.data)
            ctl.used.update(ctl.data)
        top.finish()
        return Robot(
            name=self.folder.name,
            title=title,
            folder=self.folder,
            model=model,
            tool_frame=tool_frame,
            base_frame=base_frame,
            joint_names=joint_names,
            limits=limits,
            actuators=actuators,
            gripper=gripper,
            geometry=geometry,
            sensors=sensors,
            neutral=neutral,
            controller=controller,
            family_note=family_note,
            tool_axis=tool_axis,
            roll_joint=roll,
            collision=collision,
            collision_off=collision_off,
            collision_links=self.checked.links,
            tracking_tolerance=tracking,
        )

    def _collision_edits(self, top: _Table) -> CollisionEdits:
        """robot.toml's ``[collision]`` keys on single links: ``skip``, ``stand_in``,
        ``meshes_optional`` (:mod:`robots.stand_ins`); the links are checked against the URDF
        there."""
        col = top.table("collision", {})
        optional = col.raw("meshes_optional", False)
        if not isinstance(optional, bool):
            raise col.error("meshes_optional", f"must be true or false, got {optional!r}")
        skip = col.raw("skip", [])
        if not isinstance(skip, list) or not all(isinstance(x, str) for x in skip):
            raise col.error("skip", f"must be a list of link names, got {skip!r}")
        stand_in: dict[str, StandIn] = {}
        table = col.table("stand_in", {})
        for link in list(table.data):
            t = table.table(link)
            shapes = [k for k in SHAPES if t.has(k)]
            if len(shapes) != 1:
                raise t.error(None, f"must give one of {', '.join(SHAPES)}, got {sorted(t.data)}")
            shape = shapes[0]
            size: tuple[float, ...]
            if shape == "sphere":
                size = (t.number(shape, positive=True),)
            else:
                size = tuple(t.vector(shape, SHAPES[shape]))
                if min(size) <= 0:
                    raise t.error(shape, f"must be positive, got {list(size)}")
            xyz = t.vector("xyz", 3, [0.0, 0.0, 0.0])
            rpy = t.vector("rpy", 3, [0.0, 0.0, 0.0], angle=True)
            t.finish()
            stand_in[link] = StandIn(shape, size, (xyz[0], xyz[1], xyz[2]), (rpy[0], rpy[1], rpy[2]))
        table.finish()
        return CollisionEdits(self.file, tuple(skip), stand_in, optional)

    def _load_urdf(self, urdf_name: str, meta: _Table, held: dict[str, float] | None = None) -> pin.Model:
        urdf_path = self.folder / urdf_name
        text = self.checked.text  # (read and checked once: robots/checks.py)
        try:
            text = _continuous_as_revolute(text, self.folder.name)
            if held:
                text = _held_fixed(text, held)
            model = pin.buildModelFromXML(text, mimic=True)
            self.urdf_text = text  # (as the model was built from it: the collision shapes' too)
            return model
        except Exception as e:  # Pinocchio raises ValueError/RuntimeError from C++; ElementTree ParseError
            raise RobotFileError(str(urdf_path), None, f"Pinocchio cannot load it: {e}") from None

    def _collision(
        self, top: _Table, model: pin.Model, urdf_name: str, neutral: FloatArray
    ) -> tuple[CollisionModel | None, str | None]:
        """The URDF's collision shapes, ``[world] ground`` (the floor's height [m] in the base
        frame, default 0; ``false``: none) and ``[collision] allowed`` (pairs of link names
        never checked); a neutral pose in collision is logged. A mesh that cannot be used was
        left out already, or refused the arm (robots/checks.py, robots/stand_ins.py); one that
        passed the checks and that Pinocchio or coal still cannot load refuses the arm, but with
        ``[collision] meshes_optional = true``: then no collision model, and why (said once in
        the log, and in ``info``)."""
        world = top.table("world", {})
        raw = world.raw("ground", 0.0)
        ground = None if raw is False else world.number("ground", 0.0)
        links = {f.name for f in model.frames}
        obstacles = self._obstacles(world, links)
        world.finish()
        col = top.table("collision", {})
        allowed = col.raw("allowed", [])
        if not isinstance(allowed, list) or not all(
            isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p) for p in allowed
        ):
            raise col.error("allowed", f"must be a list of [link, link] pairs, got {allowed!r}")
        for pair in allowed:
            for link in pair:
                if link not in links and link != GROUND:
                    raise col.error("allowed", f"{urdf_name} has no link {link!r}; links: {', '.join(sorted(links))}")
        for key in ("meshes_optional", "skip", "stand_in"):  # (read by _collision_edits)
            col.raw(key, None)
        col.finish()
        if self.checked.unusable:  # (only with meshes_optional: else they refused the arm)
            log.warning(
                "%s: %d mesh(es) cannot be used, left out ([collision] meshes_optional = true; the arm's other "
                "shapes, the floor and the obstacles are checked): %s",
                self.folder.name,
                len(self.checked.unusable),
                "; ".join(self.checked.unusable),
            )
        try:  # (meshes: checked inside the arm's folder, named by their paths: robots/checks.py)
            model_ = CollisionModel(
                model, self.urdf_text, ground, [(a, b) for a, b in allowed], obstacles, [str(self.folder)]
            )
        except Exception as e:  # Pinocchio's and coal's own errors (a mesh assimp cannot read, say)
            problem = f"its collision shapes cannot be loaded: {e}"
            if not self.edits.meshes_optional:
                raise RobotFileError(
                    str(self.folder / urdf_name),
                    None,
                    f"{problem} (stand in for the link with a primitive or skip it in robot.toml's [collision], "
                    "or set [collision] meshes_optional = true to serve the arm without collision checks)",
                ) from None
            off = f"{self.folder / urdf_name}: {problem}"
            log.warning("%s: served without collision checks ([collision] meshes_optional): %s", self.folder.name, off)
            return None, off
        hit = model_.first_contact(neutral)
        if hit is not None:  # (said, not refused: IK and plans do not check collisions yet)
            log.warning(
                "%s: the neutral pose is in collision: %s (set [world] ground to the floor's height in the base "
                "frame, or allow the pair in [collision] allowed if they touch by design)",
                self.folder.name,
                hit,
            )
        return model_, None

    def _obstacles(self, world: _Table, links: set[str]) -> list[Obstacle]:
        """``[[world.boxes]]`` (``size`` [x, y, z] m), ``[[world.spheres]]`` (``radius``),
        ``[[world.cylinders]]`` (``radius``, ``length``, along its z): each at ``position``
        [m] in the base frame, turned by ``rpy`` [rad], named by ``name`` (default: its kind
        and number)."""
        out: list[Obstacle] = []
        for key, kind in (("boxes", "box"), ("spheres", "sphere"), ("cylinders", "cylinder")):
            for i, t in enumerate(world.tables(key)):
                name = t.string("name", f"{kind}{i}")
                if name in links or name == GROUND or any(o.name == name for o in out):
                    raise t.error("name", f"{name!r} is taken (by a link, the ground or another obstacle)")
                if kind == "box":
                    size = tuple(t.vector("size", 3))
                    if min(size) <= 0:
                        raise t.error("size", f"must be positive, got {list(size)}")
                elif kind == "sphere":
                    size = (t.number("radius", positive=True),)
                else:
                    size = (t.number("radius", positive=True), t.number("length", positive=True))
                position = t.vector("position", 3)
                rpy = t.vector("rpy", 3, [0.0, 0.0, 0.0], angle=True)
                t.finish()
                out.append(
                    Obstacle(name, kind, size, (position[0], position[1], position[2]), (rpy[0], rpy[1], rpy[2]))
                )
        return out

    def _rooted_at(self, model: pin.Model, base_frame: str, meta: _Table, urdf_name: str) -> pin.Model:
        """``model`` with ``base_frame`` as its world frame: targets, FK, plans and lines are in
        the base frame wherever it sits in the URDF (it must be fixed to the URDF's root)."""
        frame = model.frames[frame_id(model, base_frame)]
        if frame.parentJoint != 0:
            raise meta.error(
                "base_frame",
                f"{base_frame!r} moves with joint {model.names[frame.parentJoint]!r}: the base frame must be fixed "
                f"to {urdf_name}'s root (a link that no movable joint turns)",
            )
        if frame.placement.isIdentity(1e-12):
            return model
        inverse = frame.placement.inverse()
        for j in range(1, model.njoints):
            if model.parents[j] == 0:
                model.jointPlacements[j] = inverse * model.jointPlacements[j]
        for i in range(len(model.frames)):
            if model.frames[i].parentJoint == 0:
                model.frames[i].placement = inverse * model.frames[i].placement
        return model

    def _check_joints(
        self, model: pin.Model, joint_names: tuple[str, ...], meta: _Table, urdf_name: str
    ) -> dict[str, float]:
        """The movable joints of the URDF that ``joints`` does not list (a gripper's jaw, say),
        each with the value it is held at: 0, or its limit nearer 0."""
        actuated = [model.names[i] for i in range(1, model.njoints) if model.joints[i].nq > 0]
        odd = [i for i in range(1, model.njoints) if model.joints[i].nq not in (0, 1) or model.joints[i].nv > 1]
        if model.nq != model.nv or odd:
            name = model.names[odd[0]] if odd else "?"
            raise RobotFileError(
                str(self.folder / urdf_name),
                None,
                f"joint {name!r} is a {model.joints[odd[0]].shortname() if odd else 'joint'} joint: armd takes "
                "revolute, continuous and prismatic joints (and mimic joints)",
            )
        missing = [j for j in joint_names if j not in actuated]
        if missing:
            raise meta.error(
                "joints",
                f"{urdf_name} has no movable joint {missing[0]!r}; its movable joints are: {', '.join(actuated)}",
            )
        listed = [j for j in actuated if j in joint_names]
        if listed != list(joint_names):
            raise meta.error("joints", f"must list the joints in {urdf_name}'s chain order: {', '.join(listed)}")
        held = {}
        for name in actuated:
            if name not in joint_names:
                iq = model.joints[model.getJointId(name)].idx_q
                held[name] = float(min(max(0.0, model.lowerPositionLimit[iq]), model.upperPositionLimit[iq]))
        if held:
            log.debug(
                "%s: %s not in robot.toml's joints: held at %s [rad or m]",
                self.folder.name,
                ", ".join(held),
                ", ".join(f"{v:g}" for v in held.values()),
            )
        return held

    def _limits(
        self,
        model: pin.Model,
        joint_names: tuple[str, ...],
        index: dict[str, int],
        joints: _Table,
        coupled_tables: list[_Table],
        urdf_name: str,
    ) -> tuple[JointLimits, FloatArray]:
        """The limits, and each joint's tracking tolerance [rad]."""
        n = len(joint_names)
        tracking = np.full(n, TRACKING_TOLERANCE)
        lower = np.array(model.lowerPositionLimit[:n], dtype=float)
        upper = np.array(model.upperPositionLimit[:n], dtype=float)
        velocity = np.array(model.velocityLimit[:n], dtype=float)
        acceleration = np.zeros(n)
        jerk = np.zeros(n)
        for key in joints.data:
            if key not in index:
                raise joints.error(key, f"is not a joint of this arm; joints: {', '.join(joint_names)}")
        defaulted: set[str] = set()
        for i, name in enumerate(joint_names):
            jt = joints.table(name, {})
            lower[i] = jt.number("lower", lower[i], angle=True)
            upper[i] = jt.number("upper", upper[i], angle=True)
            velocity[i] = jt.number("velocity", velocity[i])
            for key, into in (("acceleration", acceleration), ("jerk", jerk)):
                if jt.raw(key, None) is not None:  # (optional: a default from the velocity limit, below)
                    into[i] = jt.number(key, positive=True)
            tracking[i] = jt.number("tracking_tolerance", TRACKING_TOLERANCE, positive=True)
            jt.finish()
            if not (np.isfinite(lower[i]) and np.isfinite(upper[i]) and lower[i] < upper[i]):
                raise jt.error(
                    None,
                    f"position limits must be finite with lower < upper; got "
                    f"[{lower[i]}, {upper[i]}] (from {urdf_name} <limit> or this table)",
                )
            if not (np.isfinite(velocity[i]) and velocity[i] > 0):
                raise jt.error(
                    "velocity",
                    f"must be positive: {urdf_name} gives {velocity[i]:g} rad/s (<limit velocity=...>); set your "
                    f"arm's in robot.toml, [joints.{name}] velocity = ... [rad/s]",
                )
            if acceleration[i] == 0.0:
                acceleration[i] = ACCELERATION_PER_VELOCITY * velocity[i]
                defaulted.add(name)
            if jerk[i] == 0.0:
                jerk[i] = JERK_PER_ACCELERATION * acceleration[i]
                defaulted.add(name)
        if defaulted:
            log.warning(
                "%s: robot.toml gives no acceleration or jerk limit for %s: using %g x the velocity limit [1/s] "
                "and %g x that (full speed from rest in %.2f s); set [joints.<name>] acceleration and jerk to "
                "your arm's",
                self.folder.name,
                ", ".join(j for j in joint_names if j in defaulted),
                ACCELERATION_PER_VELOCITY,
                JERK_PER_ACCELERATION,
                1.0 / ACCELERATION_PER_VELOCITY + 1.0 / JERK_PER_ACCELERATION,
            )
        coupled = []
        for ct in coupled_tables:
            cname = ct.string("name")
            coeffs_t = ct.table("coefficients")
            coeffs = np.zeros(n)
            for key in coeffs_t.data:
                if key not in index:
                    raise coeffs_t.error(key, f"is not a joint of this arm; joints: {', '.join(joint_names)}")
                coeffs[index[key]] = coeffs_t.number(key)
            coeffs_t.finish()
            if not np.any(coeffs):
                raise ct.error("coefficients", "must name at least one joint with a non-zero coefficient")
            lo = ct.number("lower", -math.inf) if ct.has("lower") else -math.inf
            hi = ct.number("upper", math.inf) if ct.has("upper") else math.inf
            if not lo < hi:
                raise ct.error("upper", f"must be greater than lower ({lo} < {hi})")
            ct.finish()
            coupled.append(CoupledLimit(cname, coeffs, lo, hi))
        return JointLimits(joint_names, lower, upper, velocity, acceleration, jerk, tuple(coupled)), tracking

    def _geometry(
        self, top: _Table, index: dict[str, int], model: pin.Model, tool_frame: str, limits: JointLimits
    ) -> Geometry:
        g = top.table("geometry")

        def joint(key: str, required: bool = True) -> int | None:
            if not required and not g.has(key):
                return None
            name = g.string(key)
            if name not in index:
                raise g.error(key, f"{name!r} is not a joint of this arm; joints: {', '.join(index)}")
            return index[name]

        yaw = joint("yaw")
        shoulder = joint("shoulder")
        elbow = joint("elbow")
        wrist = joint("wrist", required=False)
        pitch = g.string("pitch", "joints")
        if pitch not in ("joints", "level"):
            raise g.error("pitch", f"must be 'joints' or 'level', got {pitch!r}")
        geom = Geometry(
            yaw=yaw,  # type: ignore[arg-type]
            shoulder=shoulder,  # type: ignore[arg-type]
            elbow=elbow,  # type: ignore[arg-type]
            wrist=wrist,
            pivot=tuple(g.vector("pivot", 3)),  # type: ignore[arg-type]
            upper_arm=g.number("upper_arm", positive=True),
            forearm=g.number("forearm", positive=True),
            hand=g.number("hand", 0.0),
            tool_offset=tuple(g.vector("tool_offset", 2, [0.0, 0.0])),  # type: ignore[arg-type]
            level=pitch == "level",
        )
        g.finish()
        used = [geom.yaw, geom.shoulder, geom.elbow] + ([geom.wrist] if geom.wrist is not None else [])
        if len(set(used)) != len(used):
            raise g.error(None, "yaw, shoulder, elbow and wrist must be different joints")
        if geom.hand < 0:
            raise g.error("hand", f"must be >= 0, got {geom.hand}")
        if geom.wrist is None and geom.hand != 0:
            raise g.error("hand", "needs a wrist joint: without one, fold the hand into forearm or tool_offset")
        if geom.level and geom.wrist is not None:
            raise g.error("pitch", "'level' (held by a linkage) excludes a wrist joint")
        self._check_geometry(g, geom, model, tool_frame, limits)
        return geom

    def _check_geometry(
        self, g: _Table, geom: Geometry, model: pin.Model, tool_frame: str, limits: JointLimits
    ) -> None:
        """The family's FK must describe the URDF: a gross mismatch is a data error.

        Small mismatches are allowed (an ideal model, as in seed 004): the QP refinement
        on the exact model removes them.
        """
        rng = np.random.default_rng(0)
        data = model.createData()
        fid = frame_id(model, tool_frame)
        reach = geom.upper_arm + geom.forearm + geom.hand + math.hypot(*geom.tool_offset)
        worst = 0.0
        for _ in range(16):
            q = rng.uniform(limits.lower, limits.upper)
            pin.forwardKinematics(model, data, q)
            p = pin.updateFramePlacement(model, data, fid).translation
            worst = max(worst, float(np.linalg.norm(p - geom.fk(q))))
        if worst > 0.05 * reach:
            raise g.error(
                None,
                f"does not describe the URDF: the family's FK is {worst:.4g} m from the URDF's "
                "tool point at some configurations (check pivot, lengths and joint names)",
            )

    def _actuators(self, top: _Table, index: dict[str, int], limits: JointLimits) -> tuple[ActuatorMap, Gripper | None]:
        n = len(index)
        servo_defaults = top.table("servo", {})
        us_per_90 = servo_defaults.number("us_per_90deg", 1000.0, positive=True)
        default_range = servo_defaults.vector("pulse_range", 2, [500.0, 2500.0])
        servo_defaults.finish()
        self._servo_defaults = (us_per_90 / (math.pi / 2), (default_range[0], default_range[1]))
        tables = top.tables("actuators")
        if not tables:  # an arm for IK, plans and simulation: a hardware adapter refuses it (it says why)
            if top.has("gripper"):
                raise top.error("gripper", "needs [[actuators]]: a gripper is driven beside the joints' actuators")
            return ActuatorMap((), np.zeros((0, n)), np.zeros(0)), None
        actuators: list[Actuator] = []
        rows = np.zeros((len(tables), n))
        offsets = np.zeros(len(tables))
        linkages: dict[int, FourBar] = {}
        channels: dict[int, str] = {}
        axes: dict[str, str] = {}
        ids: dict[int, str] = {}
        for k, t in enumerate(tables):
            name = t.string("name")
            if name in [a.name for a in actuators]:
                raise t.error("name", f"{name!r} is used twice")
            if t.has("linkage"):
                if t.has("joints") or t.has("offset"):
                    raise t.error("linkage", "gives the servo's angle: joints and offset (a = M q + b) go with it not")
                checked = _linkage(t.table("linkage"), index, limits)
                linkages[k] = checked.linkage
                rows[k] = checked.linkage.gradient(checked.middle)
                reach = checked.angle_range
            else:
                coeffs = t.table("joints")
                for key in coeffs.data:
                    if key not in index:
                        raise coeffs.error(key, f"is not a joint of this arm; joints: {', '.join(index)}")
                    rows[k, index[key]] = coeffs.number(key)
                coeffs.finish()
                if not np.any(rows[k]):
                    raise t.error("joints", "must give at least one joint a non-zero coefficient (a = M q + b)")
                offsets[k] = t.number("offset", 0.0, angle=True)
                reach = _row_range(rows[k], offsets[k], limits)
            kind = t.string("type")
            if t.has("angle_range"):
                angle_range = tuple(t.vector("angle_range", 2, angle=True))
                if not angle_range[0] < angle_range[1]:
                    raise t.error("angle_range", "must be [lower, upper] with lower < upper")
            else:
                angle_range = reach
            act: Actuator
            if kind == "servo":
                channel = t.integer("channel", minimum=0)
                if channel in channels:
                    raise t.error("channel", f"channel {channel} is already used by {channels[channel]!r}")
                channels[channel] = name
                direction = t.integer("direction", 1)
                if direction not in (1, -1):
                    raise t.error("direction", f"must be 1 or -1, got {direction}")
                pulse_range = tuple(t.vector("pulse_range", 2, default_range))
                act = Servo(
                    name=name,
                    channel=channel,
                    centre_pulse=t.number("centre_pulse", 1500.0),
                    centre_angle=t.number("centre_angle", 0.0, angle=True),
                    direction=direction,
                    us_per_rad=us_per_90 / (math.pi / 2),
                    pulse_range=pulse_range,  # type: ignore[arg-type]
                    angle_range=angle_range,  # type: ignore[arg-type]
                )
                ends = sorted(float(act.to_command(np.array(x))) for x in angle_range)
                if ends[0] < pulse_range[0] - 1e-6 or ends[1] > pulse_range[1] + 1e-6:
                    raise t.error(
                        None,
                        f"its angle range [{angle_range[0]:.4f}, {angle_range[1]:.4f}] rad maps to "
                        f"pulses [{ends[0]:.1f}, {ends[1]:.1f}] us, outside its pulse range "
                        f"{list(pulse_range)} us: fix centre_pulse/centre_angle/direction, or narrow "
                        "the joint limits or angle_range",
                    )
            elif kind == "stepper":
                axis = t.string("axis")
                if axis in axes:
                    raise t.error("axis", f"axis {axis!r} is already used by {axes[axis]!r}")
                axes[axis] = name
                act = Stepper(
                    name=name,
                    axis=axis,
                    full_steps_per_rev=t.integer("full_steps_per_rev", 200, minimum=1),
                    microsteps=t.integer("microsteps", 1, minimum=1),
                    gear=t.number("gear", 1.0, positive=True),
                    angle_range=angle_range,  # type: ignore[arg-type]
                )
            elif kind == "bus_servo":
                ident = t.integer("id", minimum=0)
                if ident > BUS_ID_MAX:
                    raise t.error("id", f"must be 0..{BUS_ID_MAX} (the bus's broadcast id is above), got {ident}")
                if ident in ids:
                    raise t.error("id", f"id {ident} is already used by {ids[ident]!r}")
                ids[ident] = name
                per_rev = t.integer("counts_per_rev", 4096, minimum=2)
                direction = t.integer("direction", 1)
                if direction not in (1, -1):
                    raise t.error("direction", f"must be 1 or -1, got {direction}")
                count_range = tuple(t.vector("range", 2, [0.0, per_rev - 1.0]))
                if not count_range[0] < count_range[1]:
                    raise t.error("range", f"must be [lower, upper] counts with lower < upper, got {list(count_range)}")
                act = BusServo(
                    name=name,
                    id=ident,
                    counts_per_rev=per_rev,
                    zero=t.number("zero", per_rev / 2.0),
                    direction=direction,
                    count_range=count_range,  # type: ignore[arg-type]
                    angle_range=angle_range,  # type: ignore[arg-type]
                )
                ends = sorted(float(act.to_command(np.array(x))) for x in angle_range)
                if ends[0] < count_range[0] - 1e-6 or ends[1] > count_range[1] + 1e-6:
                    raise t.error(
                        None,
                        f"its angle range [{angle_range[0]:.4f}, {angle_range[1]:.4f}] rad maps to "
                        f"counts [{ends[0]:.1f}, {ends[1]:.1f}], outside its range {list(count_range)}: "
                        "fix zero/direction (or calibrate), or narrow the joint limits",
                    )
            else:
                raise t.error("type", f"must be 'servo', 'stepper' or 'bus_servo', got {kind!r}")
            if angle_range[0] > reach[0] + 1e-9 or angle_range[1] < reach[1] - 1e-9:
                raise t.error(
                    "angle_range",
                    f"[{angle_range[0]:.4f}, {angle_range[1]:.4f}] rad does not cover what "
                    f"the joint limits allow, [{reach[0]:.4f}, {reach[1]:.4f}] rad: narrow the joint limits",
                )
            t.finish()
            actuators.append(act)
        if np.linalg.matrix_rank(rows) < n:
            raise top.error(
                "actuators",
                f"do not determine every joint: the rows of M must have rank {n} (each joint driven by some actuator)",
            )
        driven = sorted({link.driven for link in linkages.values()})
        linear = [k for k in range(len(tables)) if k not in linkages]
        free = [j for j in range(n) if j not in driven]
        if (
            len(driven) < len(linkages)
            or any(link.input in driven for link in linkages.values())  # (a chain: one's input another's output)
            or np.any(rows[np.ix_(linear, driven)])
            or np.linalg.matrix_rank(rows[np.ix_(linear, free)]) < len(free)
        ):
            raise top.error(
                "actuators",
                "with a linkage: each linkage drives a joint of its own, which no other actuator's joints "
                "name and no linkage takes as its input, and the other actuators determine every other joint "
                "(the linkages' inputs among them)",
            )
        gripper = None
        if top.has("gripper"):
            gt = top.table("gripper")
            if ids:  # a bus servo's id
                channel = gt.integer("id", minimum=0)
                if channel in ids or channel > BUS_ID_MAX:
                    raise gt.error("id", f"id {channel} is already used by {ids.get(channel)!r} or above {BUS_ID_MAX}")
            else:
                channel = gt.integer("channel", minimum=0)
                if channel in channels:
                    raise gt.error("channel", f"channel {channel} is already used by {channels[channel]!r}")
            gripper = Gripper(channel=channel, closed=gt.number("closed"), open=gt.number("open"))
            gt.finish()
        return ActuatorMap(tuple(actuators), rows, offsets, linkages), gripper

    def _sensors(
        self, top: _Table, frames: set[str], actuators: ActuatorMap, gripper: Gripper | None
    ) -> dict[str, RangeSensor]:
        out: dict[str, RangeSensor] = {}
        ssc32 = top.has("controller") and top.table("controller").data.get("type") == "ssc32"
        channels = {a.channel: a.name for a in actuators.actuators if isinstance(a, Servo)}
        if gripper is not None:
            channels[gripper.channel] = "the gripper"
        pins: dict[str, str] = {}
        for t in top.tables("sensors"):
            name = t.string("name")
            if name in out:
                raise t.error("name", f"{name!r} is used twice")
            model_name = t.string("model", "range sensor")
            rng = t.vector("range", 2)
            if not 0 <= rng[0] < rng[1]:
                raise t.error("range", f"must be [min, max] with 0 <= min < max [m], got {rng}")
            mount = t.string("mount")
            if mount == "scanner":
                x, y, z = t.vector("position", 3)
                sweep = t.vector("sweep", 2, [-1.0, 1.0], angle=True)  # [rad] its scanning servo's bearings
                if not -math.pi <= sweep[0] < sweep[1] <= math.pi:
                    raise t.error("sweep", f"must be [first, last] in [-pi, pi] rad, first < last, got {sweep}")
                step = t.number("sweep_step", 0.035, positive=True, angle=True)
                if t.has("pin") != t.has("channel"):
                    raise t.error(
                        "pin" if t.has("channel") else "channel",
                        "a scanner wired to the SSC-32 needs both: its output's pin and its servo's channel",
                    )
                out[name] = RangeSensor(
                    name,
                    model_name,
                    mount,
                    (rng[0], rng[1]),
                    position=(x, y, z),
                    sweep=(sweep[0], sweep[1]),
                    sweep_step=step,
                    pin=self._pin(t, ssc32, pins, name),
                    servo=self._scanning_servo(t, ssc32, channels, name, (sweep[0], sweep[1])),
                )
            elif mount == "frame":
                frame = t.string("frame")
                if frame not in frames:
                    raise t.error("frame", f"the URDF has no frame {frame!r}")
                pin = self._pin(t, ssc32, pins, name)
                out[name] = RangeSensor(name, model_name, mount, (rng[0], rng[1]), frame=frame, pin=pin)
            else:
                raise t.error("mount", f"must be 'scanner' or 'frame', got {mount!r}")
            t.finish()
        return out

    def _pin(self, t: _Table, ssc32: bool, pins: dict[str, str], name: str) -> str | None:
        """``pin``: the SSC-32U analog input ("A".."H") the sensor's output is wired to."""
        if not t.has("pin"):
            return None
        if not ssc32:
            raise t.error("pin", "is an SSC-32U's analog input: this arm's [controller] is not an SSC-32")
        pin = t.string("pin").upper()
        if len(pin) != 1 or pin not in "ABCDEFGH":
            raise t.error("pin", f"must be one of the SSC-32U's analog inputs A to H, got {pin!r}")
        if pin in pins:
            raise t.error("pin", f"pin {pin} is already {pins[pin]!r}'s")
        pins[pin] = name
        return pin

    def _scanning_servo(
        self, t: _Table, ssc32: bool, channels: dict[int, str], name: str, sweep: tuple[float, float]
    ) -> Servo | None:
        """``channel`` (with ``centre_pulse``, ``direction``): the scanner's servo on the SSC-32;
        its angle is the bearing, and its sweep must map inside its pulse range."""
        if not t.has("channel"):
            for key in ("centre_pulse", "direction"):
                if t.has(key):
                    raise t.error(key, "goes with channel (the scanning servo's)")
            return None
        if not ssc32:
            raise t.error("channel", "is an SSC-32 channel: this arm's [controller] is not an SSC-32")
        channel = t.integer("channel", minimum=0)
        if channel > 31:
            raise t.error("channel", f"must be 0..31, got {channel}")
        if channel in channels:
            raise t.error("channel", f"channel {channel} is already {channels[channel]!r}'s")
        direction = t.integer("direction", 1)
        if direction not in (1, -1):
            raise t.error("direction", f"must be 1 or -1, got {direction}")
        us_per_rad, pulse_range = self._servo_defaults
        servo = Servo(
            name=f"{name} scanner",
            channel=channel,
            centre_pulse=t.number("centre_pulse", 1500.0),
            centre_angle=0.0,
            direction=direction,
            us_per_rad=us_per_rad,
            pulse_range=pulse_range,
            angle_range=sweep,
        )
        ends = sorted(float(servo.to_command(np.array(b))) for b in sweep)
        if ends[0] < pulse_range[0] or ends[1] > pulse_range[1]:
            raise t.error(
                None,
                f"its sweep [{sweep[0]:.4f}, {sweep[1]:.4f}] rad maps to pulses [{ends[0]:.1f}, {ends[1]:.1f}] us, "
                f"outside {list(pulse_range)} us",
            )
        channels[channel] = f"{name} scanner"
        return servo


_AXES = {"x": 0, "y": 1, "z": 2}


def _tool_axis(meta: _Table) -> np.ndarray:
    """``[robot] tool_axis``: "+x" (the default), "-y", ... or a vector in the tool frame."""
    raw = meta.raw("tool_axis", "+x")
    if isinstance(raw, str):
        text = raw.strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        name = text.lstrip("+-")
        if name not in _AXES:
            raise meta.error("tool_axis", f"must be one of +x, -x, +y, -y, +z, -z or a vector [x, y, z], got {raw!r}")
        axis = np.zeros(3)
        axis[_AXES[name]] = sign
        return axis
    v = np.array(meta.vector("tool_axis", 3))
    norm = float(np.linalg.norm(v))
    if norm < 1e-9:
        raise meta.error("tool_axis", f"must not be zero, got {raw!r}")
    return v / norm


def _shape(g: Geometry, n: int) -> str:
    """The family's shape in words ("yaw + 3 pitch + roll")."""
    pitches = 3 if g.has_wrist else 2
    return f"yaw + {pitches} pitch" + (" + roll" if n > pitches + 1 else "")


def _held_fixed(urdf: str, held: dict[str, float]) -> str:
    """``urdf`` with each joint of ``held`` made fixed at its value (its origin moved by it)."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(urdf)
    for joint in root.iter("joint"):
        name = joint.get("name", "")
        if name not in held:
            continue
        origin = joint.find("origin")
        xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
        axis_el = joint.find("axis")
        axis = np.array([float(v) for v in (axis_el.get("xyz", "1 0 0") if axis_el is not None else "1 0 0").split()])
        axis /= np.linalg.norm(axis)
        value = held[name]
        moved = pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)
        if joint.get("type") == "prismatic":
            moved = moved * pin.SE3(np.eye(3), axis * value)
        else:
            moved = moved * pin.SE3(pin.AngleAxis(value, axis).matrix(), np.zeros(3))
        for child in list(joint):
            if child.tag in ("axis", "limit", "dynamics", "safety_controller", "calibration", "origin"):
                joint.remove(child)
        joint.set("type", "fixed")
        ET.SubElement(
            joint,
            "origin",
            {
                "xyz": " ".join(repr(float(v)) for v in moved.translation),
                "rpy": " ".join(repr(float(v)) for v in pin.rpy.matrixToRpy(moved.rotation)),
            },
        )
    return ET.tostring(root, encoding="unicode")


def _continuous_as_revolute(urdf: str, arm: str) -> str:
    """``urdf`` with each continuous joint made revolute over [-2 pi, 2 pi] (a joint of ``q``
    like any other: Pinocchio would give it two coordinates, cos and sin; the limits can be
    narrowed in robot.toml, [joints.<name>] lower/upper). Said once, in the log."""
    if 'type="continuous"' not in urdf and "type='continuous'" not in urdf:
        return urdf
    import xml.etree.ElementTree as ET

    root = ET.fromstring(urdf)
    changed = []
    for joint in root.iter("joint"):
        if joint.get("type") != "continuous":
            continue
        joint.set("type", "revolute")
        limit = joint.find("limit")
        if limit is None:
            limit = ET.SubElement(joint, "limit", {"effort": "0", "velocity": "0"})
        limit.set("lower", repr(-CONTINUOUS_RANGE))
        limit.set("upper", repr(CONTINUOUS_RANGE))
        changed.append(joint.get("name", "?"))
    log.info(
        "%s: continuous joint(s) %s: limits [-2 pi, 2 pi] rad (narrow them in robot.toml, [joints.<name>] lower/upper)",
        arm,
        ", ".join(changed),
    )
    return ET.tostring(root, encoding="unicode")


@dataclass(frozen=True)
class _Linkage:
    linkage: FourBar
    angle_range: tuple[float, float]
    middle: np.ndarray  # a joint vector in the middle of the linkage's range


def _linkage(t: _Table, index: dict[str, int], limits: JointLimits) -> _Linkage:
    """``[actuators.linkage]``: a four-bar (robots/linkages.py), proven over the joint limits."""
    kind = t.string("type", "four_bar")
    if kind != "four_bar":
        raise t.error("type", f"must be 'four_bar', got {kind!r}")

    def joint(key: str) -> int:
        name = t.string(key)
        if name not in index:
            raise t.error(key, f"{name!r} is not a joint of this arm; joints: {', '.join(index)}")
        return index[name]

    link = FourBar(
        input=joint("input"),
        driven=joint("driven"),
        frame=t.number("frame", positive=True),
        lever=t.number("lever", positive=True),
        rod=t.number("rod", positive=True),
        horn=t.number("horn", positive=True),
        bend=t.number("bend", 0.0, angle=True),
        assembly=t.integer("assembly", 1),
    )
    t.finish()
    if link.input == link.driven:
        raise t.error("driven", "must be another joint than input")
    if link.assembly not in (1, -1):
        raise t.error("assembly", f"must be 1 or -1, got {link.assembly}")
    coupled = [(c.coefficients, c.lower, c.upper) for c in limits.coupled]
    pts = linkage_region(limits.lower, limits.upper, coupled, (link.input, link.driven))
    try:
        checked = link.check(pts)
    except ValueError as e:
        raise t.error(None, str(e)) from None
    return _Linkage(checked.linkage, checked.angle_range, np.mean(pts, axis=0))


def _row_range(row: np.ndarray, offset: float, limits: JointLimits) -> tuple[float, float]:
    """The interval an actuator angle ``row . q + offset`` spans over the joint limits.

    Interval arithmetic over the box, narrowed by a coupled limit on the same combination
    of joints (the desk4 minor servo: ``q2 + q3`` is bounded by the linkage).
    """
    lo = offset + float(np.sum(np.minimum(row * limits.lower, row * limits.upper)))
    hi = offset + float(np.sum(np.maximum(row * limits.lower, row * limits.upper)))
    for c in limits.coupled:
        ratio = _proportional(row, c.coefficients)
        if ratio is not None:
            a, b = sorted((ratio * c.lower, ratio * c.upper))
            lo, hi = max(lo, offset + a), min(hi, offset + b)
    return lo, hi


def _proportional(row: np.ndarray, coeffs: np.ndarray) -> float | None:
    j = int(np.argmax(np.abs(coeffs)))
    ratio = row[j] / coeffs[j]
    return float(ratio) if ratio != 0 and np.allclose(row, ratio * coeffs, atol=1e-12) else None
