"""The JSON protocol (version 1): request validation and reply shapes, independent of Zenoh.

Every request is a JSON object; every reply is a JSON object. A bad request raises
:class:`BadRequest` naming the ``field`` by its path (``start.jerk``, ``q[1]``,
``via[0].target``); the service turns any :class:`ArmdError` into an error reply
``{"code", "message", ...}`` in one place. Each verb's request has a shape here (``FK``,
``IK_ONE``, ``IK_BATCH``, ``PLAN``, ``MOVE``, ``GRIPPER``, ``NOTHING``), checked whole
before anything is solved: unknown keys at every level, numbers that are JSON numbers
(not true/false), finite and of a sane size, fields that exclude each other. The full
description, with a JSON Schema per verb, is ``docs/protocol.md``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import orjson

from armd.errors import ArmdError, BadRequest, PayloadTooLarge

PROTOCOL_VERSION = 1
VERBS = ("info", "fk", "ik", "plan", "move", "stop", "gripper", "world", "detect", "pick", "place")
ENVELOPE = ("protocol", "deadline")  # fields any request may carry, whatever its verb


@dataclass(frozen=True)
class Limits:
    """What the operator allows per request (``armd serve --max-...``, ``--deadline``;
    defaults documented in docs/protocol.md and docs/reliability.md)."""

    max_payload_bytes: int = 1_000_000
    max_batch: int = 10_000  # targets in one IK batch
    max_depth: int = 8  # nesting depth of a request's JSON
    max_waypoints: int = 100  # via points of one plan or move
    max_samples: int = 20_000  # samples of one trajectory (400 s at 50 Hz, 20 s at 1 kHz)
    deadline: float = 4.0  # [s] from a request's arrival to its reply (below ArmClient's 5 s timeout)

    def __post_init__(self) -> None:
        for name in ("max_payload_bytes", "max_batch", "max_depth", "max_waypoints", "max_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise BadRequest(f"{name} must be a whole number >= 1, got {value!r}", field=name)
        d = self.deadline
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not math.isfinite(d) or d <= 0:
            raise BadRequest(f"deadline must be a number of seconds > 0, got {d!r}", field="deadline")


def request_deadline(req: Mapping[str, Any]) -> float | None:
    """The request's own ``deadline`` [s] (optional; null is absent), or :class:`BadRequest`."""
    v = req.get("deadline")
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise BadRequest(f"deadline must be a number of seconds > 0, got {v!r}", field="deadline")
    return float(v)


def decode(payload: bytes | None, limits: Limits) -> dict[str, Any]:
    """The request object from a payload (empty or absent: ``{}``); :class:`BadRequest` otherwise."""
    if payload is None or len(payload) == 0:
        return {}
    if len(payload) > limits.max_payload_bytes:
        raise PayloadTooLarge(len(payload), limits.max_payload_bytes)
    try:  # strict JSON: NaN, Infinity and numbers beyond a double (1e999) are refused; so is any byte
        obj = orjson.loads(payload)  # sequence that is not UTF-8 (orjson checks all of the input)
    except orjson.JSONDecodeError as e:
        try:  # (only now, on the way out: which of the two it was)
            payload.decode("utf-8")
        except UnicodeDecodeError:
            raise BadRequest("the payload is not UTF-8 text (a JSON object is expected)", field="payload") from None
        raise BadRequest(f"the payload is not valid JSON: {e}", field="payload") from None
    if not isinstance(obj, dict):
        raise BadRequest(f"the request must be a JSON object, got {type(obj).__name__}", field="payload")
    # Every level of nesting opens with a bracket, and a scalar adds one: with fewer brackets
    # than the limit the request cannot be too deep, and is not walked (one target: two).
    if payload.count(b"[") + payload.count(b"{") >= limits.max_depth and _deeper_than(obj, limits.max_depth):
        raise BadRequest(f"the request is nested deeper than {limits.max_depth} levels", field="payload")
    version = obj.get("protocol")
    if version is None:  # absent, or null: an optional field given as null is absent
        return obj
    if version != PROTOCOL_VERSION or isinstance(version, bool):
        raise BadRequest(
            f"protocol version {version!r} is not spoken here; this service speaks {PROTOCOL_VERSION}", field="protocol"
        )
    return obj


def _deeper_than(obj: object, limit: int) -> bool:
    """Whether parsed JSON nests deeper than ``limit`` levels (a scalar inside a container is one
    level deeper). Walked with a stack of its own, and left as soon as the limit is passed: no
    nesting (orjson parses up to 1024 levels) reaches Python's recursion limit here."""
    stack: list[tuple[object, int]] = [(obj, 1)]
    while stack:
        node, level = stack.pop()
        for v in node.values() if isinstance(node, dict) else node:  # type: ignore[attr-defined]
            if isinstance(v, (dict, list)):
                if level + 1 > limit:
                    return True
                stack.append((v, level + 1))
            elif level + 1 > limit:
                return True
    return False


def encode(obj: Mapping[str, Any]) -> bytes:
    """A reply as JSON bytes (NaN and infinities, which JSON lacks, become null; NumPy arrays
    become lists)."""
    try:
        return orjson.dumps(obj, option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:  # what orjson cannot write (an integer beyond 64 bits echoed back): the json module
        return json.dumps(_finite(obj), separators=(",", ":"), default=_plain).encode()


def _plain(obj: Any) -> Any:
    if hasattr(obj, "tolist"):  # NumPy arrays and scalars
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def error_reply(err: ArmdError) -> bytes:
    return encode(err.to_dict())


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def allowed(req: Mapping[str, Any], *names: str) -> None:
    """Refuse keys a verb does not know (a misspelt option must not be silently ignored)."""
    known = _KNOWN.get(names)
    if known is None:  # once per verb: the names are the handlers' constants
        known = _KNOWN[names] = frozenset(names + ENVELOPE)
    if known.issuperset(req):
        return
    extra = sorted(set(req) - known)
    raise BadRequest(f"unknown field {extra[0]!r}; this verb takes: {', '.join(names)}", field=extra[0])


_KNOWN: dict[tuple[str, ...], frozenset[str]] = {}


def number(req: Mapping[str, Any], name: str, default: float | None = None) -> float | None:
    v = req.get(name)
    if v is None:  # absent, or null: the default
        return default
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise BadRequest(f"{name} must be a finite number, got {v!r}", field=name)
    return float(v)


def flag(req: Mapping[str, Any], name: str, default: bool = False) -> bool:
    v = req.get(name, default)
    if not isinstance(v, bool):
        raise BadRequest(f"{name} must be true or false, got {v!r}", field=name)
    return v


# -- request shapes --------------------------------------------------------------------------
#
# What a value means for one arm (its joint limits, its sensors, its reach, a speed Ruckig can
# time) is checked later, by the solvers and the planner. The sizes here only keep out what no
# request can mean, before it reaches code that would overflow on it (a line 1e308 m long).

MAX_METRES = 10.0  # [m] a Cartesian coordinate or a sensor reading: beyond any small arm's reach
MAX_RADIANS = 100.0  # [rad] (m for a prismatic joint) a joint value, a bearing: 16 turns
MAX_RATE = 1e6  # [rad/s], [rad/s^2] a start state's velocity or acceleration (its limits come later)
MAX_NAME = 64  # characters of a name (a sensor's)
APPROACH_WORDS = ("parallel", "perpendicular", "free")  # solvers.APPROACHES (tests check they agree)
PATH_WORDS = ("joint", "line")  # planning.PATHS
Joints = Sequence[str]  # the arm's joint names: how long a joint vector is


def _show(v: object) -> str:
    """A value as the client wrote it (JSON), cut short."""
    try:
        text = json.dumps(v)
    except (TypeError, ValueError):
        text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _kind(v: object) -> str:
    """The JSON type of a parsed value (true and false are not numbers, whatever Python says)."""
    t = type(v)
    if t is float or t is int:
        return "number"
    if t is str:
        return "string"
    if t is list or t is tuple:
        return "list"
    if isinstance(v, Mapping):
        return "object"
    if t is bool:
        return "boolean"
    if v is None:
        return "null"
    if isinstance(v, (int, float)):  # NumPy scalars, from Python callers
        return "number"
    if hasattr(v, "tolist"):  # NumPy arrays
        return "list"
    return type(v).__name__


def _items(v: object) -> Sequence[Any]:
    """A list's items (a NumPy array's, as a list: from Python callers)."""
    tolist = getattr(v, "tolist", None)
    out: Sequence[Any] = tolist() if tolist is not None else v  # type: ignore[assignment]
    return out


def real(v: object, field: str, lo: float = -math.inf, hi: float = math.inf, unit: str = "") -> float:
    """``v`` as a float if it is a JSON number (not a boolean), finite, in [lo, hi]; else
    :class:`BadRequest` naming ``field``. An integer too large for a double is refused, not
    overflowed."""
    if type(v) is float:
        if lo <= v <= hi and v - v == 0.0:  # (NaN fails the comparison, an infinity the difference)
            return v
    elif _kind(v) == "number":
        try:
            f = float(v)  # type: ignore[arg-type]
        except OverflowError:  # an integer beyond a double
            f = math.inf
        if lo <= f <= hi and math.isfinite(f):
            return f
    if math.isinf(lo) and math.isinf(hi):
        want = f"a finite number [{unit}]" if unit else "a finite number"
        raise BadRequest(f"{field} must be {want}, got {_show(v)}", field=field)
    unit = f" {unit}" if unit else ""
    want = f"a number within +-{hi:g}{unit}" if lo == -hi else f"a number in [{lo:g}, {hi:g}]{unit}"
    raise BadRequest(f"{field} must be {want}, got {_show(v)}", field=field)


class Shape:
    """What a request value must look like. :meth:`check` returns the value (an object with
    its null members dropped: null is absent) or raises :class:`BadRequest` at its path."""

    what = "a value"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        return v


ANY = Shape()  # checked elsewhere (the envelope: protocol, deadline)


@dataclass(frozen=True)
class Num(Shape):
    """A finite JSON number in [lo, hi] ``unit``."""

    unit: str = ""
    lo: float = -math.inf
    hi: float = math.inf

    @property
    def what(self) -> str:  # type: ignore[override]
        return f"a number [{self.unit}]" if self.unit else "a number"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        return real(v, field, self.lo, self.hi, self.unit)


@dataclass(frozen=True)
class Vec(Shape):
    """A list of ``n`` numbers (None: one per joint), each within +-``bound`` ``unit``."""

    n: int | None
    unit: str
    bound: float

    @property
    def what(self) -> str:  # type: ignore[override]
        return f"a list of {self.n if self.n is not None else 'joint'} values [{self.unit}]"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        if _kind(v) != "list":
            raise BadRequest(f"{field} must be {self.what}, got {_show(v)}", field=field)
        items = _items(v)
        n = len(joints) if self.n is None else self.n
        if len(items) != n:
            names = f" ({', '.join(joints)})" if self.n is None else ""
            raise BadRequest(f"{field} must have {n} values{names}, got {len(items)}", field=field)
        b = self.bound
        for x in items:
            if type(x) is not float or not -b <= x <= b:  # (the common case: floats within bounds)
                break
        else:
            return v
        for i, x in enumerate(items):
            real(x, f"{field}[{i}]", -b, b, self.unit)
        return v


@dataclass(frozen=True)
class Rows(Shape):
    """One ``row`` for all, or a list of rows (one per item of a batch)."""

    row: Vec

    what = "one list of values or a list of them"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        if _kind(v) == "list" and len(v) > 0 and _kind(v[0]) == "list":  # type: ignore[arg-type,index]
            return ListOf(self.row).check(v, field, joints)
        return self.row.check(v, field, joints)


@dataclass(frozen=True)
class ListOf(Shape):
    """A list, each item of ``item``'s shape (``field[i]``), at least ``min_items`` of them and
    at most ``max_items`` (counted before any item is looked at: a long list costs nothing)."""

    item: Shape
    min_items: int = 0
    items_are: str = ""  # what the items are, for messages (default: the item's shape says)
    max_items: int | None = None

    @property
    def what(self) -> str:  # type: ignore[override]
        return f"a list of {self.items_are or self.item.what}"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        if _kind(v) != "list":
            raise BadRequest(f"{field} must be {self.what}, got {_show(v)}", field=field)
        items = _items(v)
        if len(items) < self.min_items:
            raise BadRequest(f"{field} must have at least {self.min_items} item(s), got {len(items)}", field=field)
        if self.max_items is not None and len(items) > self.max_items:
            raise BadRequest(f"{field} may have at most {self.max_items} item(s), got {len(items)}", field=field)
        out = [self.item.check(x, f"{field}[{i}]", joints) for i, x in enumerate(items)]
        return v if all(a is b for a, b in zip(out, items, strict=True)) else out


@dataclass(frozen=True)
class Word(Shape):
    """A string: one of ``words``, or (none given) any of at most MAX_NAME characters."""

    words: tuple[str, ...] = ()

    @property
    def what(self) -> str:  # type: ignore[override]
        return "one of " + ", ".join(f"{w!r}" for w in self.words) if self.words else "a name (a string)"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        if type(v) is str and (v in self.words if self.words else 0 < len(v) <= MAX_NAME):
            return v
        raise BadRequest(f"{field} must be {self.what}, got {_show(v)}", field=field)


@dataclass(frozen=True)
class Flag(Shape):
    what = "true or false"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        if type(v) is bool:
            return v
        raise BadRequest(f"{field} must be true or false, got {_show(v)}", field=field)


@dataclass(frozen=True)
class Either(Shape):
    """One of several shapes, chosen by the value's JSON type (``list``, ``object``,
    ``string``, ``number``)."""

    options: Mapping[str, Shape]
    what: str = "a value"

    def check(self, v: object, field: str, joints: Joints) -> Any:
        shape = self.options.get(_kind(v))
        if shape is None:
            raise BadRequest(f"{field} must be {self.what}, got {_show(v)}", field=field)
        return shape.check(v, field, joints)


@dataclass(frozen=True)
class Obj(Shape):
    """An object with these ``fields`` and no other: ``required`` ones (name, what it is),
    at most one of each ``exclusive`` pair, and exactly one of ``one_of`` (when given).
    ``top``: the request itself (its fields are named bare, and the envelope is allowed)."""

    fields: Mapping[str, Shape]
    required: tuple[tuple[str, str], ...] = ()
    exclusive: tuple[tuple[str, str, str], ...] = ()  # (a, b, why)
    one_of: tuple[str, ...] = ()
    what: str = "an object"
    top: bool = False

    def check(self, v: object, field: str, joints: Joints) -> Any:
        if not isinstance(v, Mapping):
            raise BadRequest(f"{field} must be {self.what}, got {_show(v)}", field=field)
        prefix = f"{field}." if field else ""
        known = self.fields
        if self.top:
            for k in v:
                if k not in known and k not in ENVELOPE:
                    raise BadRequest(f"unknown field {k!r}; this verb takes: {', '.join(known) or 'nothing'}", field=k)
        else:
            for k in v:
                if k not in known:
                    raise BadRequest(
                        f"unknown field {prefix + k!r} ({field} takes: {', '.join(known)})", field=f"{prefix}{k}"
                    )
        obj: Mapping[str, Any] = v
        if any(x is None for x in v.values()):  # null is absent
            obj = {k: x for k, x in v.items() if x is not None}
        where = "the request" if self.top else field
        for name, desc in self.required:
            if name not in obj:
                raise BadRequest(f"{where} needs {name!r}, {desc}", field=prefix + name)
        for a, b, why in self.exclusive:
            if a in obj and b in obj:
                raise BadRequest(f"{prefix}{a} and {prefix}{b} exclude each other: {why}", field=prefix + b)
        if self.one_of and not any(name in obj for name in self.one_of):
            raise BadRequest(
                f"{where} needs one of {', '.join(repr(n) for n in self.one_of)}", field=field or self.one_of[0]
            )
        changed = obj is not v
        out = dict(obj) if changed else None
        for k, x in obj.items():
            shape = known.get(k, ANY)
            y = shape.check(x, prefix + k, joints)
            if y is not x:
                if out is None:
                    out = dict(obj)
                out[k] = y
        return obj if out is None else out


PLAIN_POINT = frozenset(("target", *ENVELOPE))


def plain_point(req: Mapping[str, Any]) -> list[float] | None:
    """The target of the commonest request, an IK of one point and nothing else
    (``{"target": [x, y, z]}``, the envelope aside), when its three coordinates are floats
    within ``MAX_METRES``: what ``check(IK_ONE, req)`` passes unchanged, seen in one pass
    instead of the shapes' walk (a third of the service's own time per request). None for
    anything else, which takes the full check."""
    t = req.get("target")
    if type(t) is not list or len(t) != 3 or not PLAIN_POINT.issuperset(req):
        return None
    for x in t:
        if type(x) is not float or not -MAX_METRES <= x <= MAX_METRES:
            return None
    return t


def check(shape: Obj, req: Mapping[str, Any], joints: Joints = ()) -> dict[str, Any]:
    """The request checked whole against its verb's ``shape`` (null members dropped), or
    :class:`BadRequest` naming the first field that is wrong by its path."""
    out: dict[str, Any] = shape.check(req, "", joints)
    return out


# The verbs' shapes (docs/protocol.md has them as JSON Schemas).
POINT = Vec(3, "m", MAX_METRES)
JOINTS = Vec(None, "rad", MAX_RADIANS)
PITCH = Num("rad", -math.pi, math.pi)
MAX_VOLTS = 100.0  # [V] a sensor's output: beyond any range sensor's
SENSOR_READING = Obj(
    {
        "sensor": Word(),
        "range": Num("m", -MAX_METRES, MAX_METRES),
        "volts": Num("V", -MAX_VOLTS, MAX_VOLTS),
        "bearing": Num("rad", -MAX_RADIANS, MAX_RADIANS),
    },
    required=(("sensor", "the sensor's name"),),
    exclusive=(("range", "volts", "a reading is a range [m] or the sensor's output [V]"),),
    one_of=("range", "volts"),
    what='a sensor reading {"sensor", "range" or "volts", "bearing"}',
)
TARGET = Either(
    {"list": POINT, "object": SENSOR_READING},
    'a point [x, y, z] in metres or a sensor reading {"sensor", "range", "bearing"}',
)
APPROACH = Either(
    {"string": Word(APPROACH_WORDS), "number": PITCH}, "'parallel', 'perpendicular', 'free' or a pitch in [-pi, pi] rad"
)
APPROACHES = Either(
    {"string": Word(APPROACH_WORDS), "number": PITCH, "list": ListOf(PITCH)},
    "'parallel', 'perpendicular', 'free', a pitch in [-pi, pi] rad or one pitch per target",
)
GOAL = Either(
    {
        "list": JOINTS,
        "object": Obj(
            {"target": TARGET, "approach": APPROACH, "roll": PITCH, "q": JOINTS},
            exclusive=(
                ("target", "q", "a goal is a Cartesian target or a joint vector"),
                ("q", "approach", "an approach is for a Cartesian target"),
                ("q", "roll", "a roll is for a Cartesian target"),
            ),
            one_of=("target", "q"),
            what='a goal {"target", "approach"} or {"q"}',
        ),
    },
    'a joint vector [rad], {"target": [x, y, z], "approach": ...} or {"q": [...]}',
)
START = Either(
    {
        "list": JOINTS,
        "object": Obj(
            {
                "position": JOINTS,
                "velocity": Vec(None, "rad/s", MAX_RATE),
                "acceleration": Vec(None, "rad/s^2", MAX_RATE),
            },
            required=(("position", "the joint vector [rad]"),),
            what='a state {"position", "velocity", "acceleration"}',
        ),
    },
    'a joint vector [rad] or {"position", "velocity", "acceleration"}',
)
_MOTION = {
    "goal": GOAL,
    "path": Word(PATH_WORDS),
    "speed": Num(),
    "rate_hz": Num("Hz"),
    "via": ListOf(GOAL, items_are="goals"),
}

NOTHING = Obj({}, top=True)  # robots, info, stop
FK = Obj({"q": JOINTS}, required=(("q", "the joint vector [rad]"),), top=True)
# (ik: the handler picks IK_ONE or IK_BATCH by which of target and targets is there, and refuses
# both; the other one is named in each so that it may be given as null, which is absent)
IK_ONE = Obj(
    {
        "target": TARGET,
        "approach": APPROACH,
        "roll": PITCH,
        "seed": JOINTS,
        "tolerance": Num("m"),
        "quantise": Flag(),
        "targets": ANY,
    },
    required=(("target", "[x, y, z] in metres, or a sensor reading (or 'targets', a batch)"),),
    top=True,
)
IK_BATCH = Obj(
    {
        "targets": ListOf(POINT, min_items=1, items_are="[x, y, z] points in metres"),
        "approach": APPROACHES,
        "seeds": Rows(JOINTS),
        "tolerance": Num("m"),
        "target": ANY,
    },
    required=(("targets", "a list of [x, y, z] points"),),
    top=True,
)
PLAN = Obj({"start": START, **_MOTION}, required=(("goal", 'a joint vector, or {"target": [x, y, z], ...}'),), top=True)
MOVE = Obj(_MOTION, required=PLAN.required, top=True)
GRIPPER = Obj({"opening": Num("", 0.0, 1.0)}, required=(("opening", "from 0 (closed) to 1 (open)"),), top=True)
SEQUENCE = Obj(  # pick and place
    {
        "target": TARGET,
        "approach": Word(("perpendicular", "parallel")),
        "above": Num("m", 0.0, 0.3),
        "lift": Num("m", 0.0, 0.3),
        "speed": Num(),
    },
    required=(("target", "[x, y, z] in metres (the object's centre where it is grasped), or a sensor reading"),),
    top=True,
)
MAX_SWEEPS = 4  # sweeps one detect may look at (fresh ones: service/sensor_book.py MAX_AGE)
DETECT = Obj(
    {
        "sensors": ListOf(Word(), min_items=1, items_are="scanning sensors' names"),
        "sweeps": Num("", 1, MAX_SWEEPS),
    },
    top=True,
)
# an obstacle's shapes: robots.collision.SIZES's (not imported: the client loads this module
# without Pinocchio; tests/test_world.py checks they agree)
SHAPES = ("box", "sphere", "cylinder")
MIN_SIZE = 0.0005  # [m] an obstacle's smallest dimension
MAX_OBSTACLES = 64  # obstacles added at run time, per arm
# [bytes] a world request, at most, refused by its size before it is parsed: 64 obstacles are
# under 20 KB, and one of thousands would hold the interpreter (and so every stop) while it is parsed
WORLD_BYTES = 64 * 1024
OBSTACLE = Obj(
    {
        "name": Word(),
        "shape": Word(SHAPES),
        "size": ListOf(Num("m", MIN_SIZE, MAX_METRES), min_items=1, items_are="sizes [m]"),
        "position": POINT,
        "rpy": Vec(3, "rad", MAX_RADIANS),
    },
    required=(
        ("name", "a name of its own"),
        ("shape", "'box', 'sphere' or 'cylinder'"),
        ("size", "[x, y, z] (box), [radius] (sphere) or [radius, length] (cylinder) in metres"),
        ("position", "its centre [x, y, z] in metres, in the base frame"),
    ),
    what='an obstacle {"name", "shape", "size", "position", "rpy"}',
)
WORLD = Obj(
    {
        "add": ListOf(OBSTACLE, min_items=1, items_are="obstacles", max_items=MAX_OBSTACLES),
        "remove": ListOf(Word(), min_items=1, items_are="obstacle names", max_items=MAX_OBSTACLES),
        "clear": Flag(),
    },
    top=True,
)
