"""A put on ``<prefix>/<robot>/track``: what it must look like (docs/protocol.md, "Tracking").

``{"session": <id>, "seq": <int, rising>}`` and exactly one of ``joints`` [rad], ``target``
[x, y, z] [m] (with ``approach``, ``roll`` as ``ik`` takes them) or ``velocity`` [vx, vy, vz]
[m/s] (with ``pitch_rate``, ``roll_rate`` [rad/s]: jogging); optional ``speed`` in (0, 1],
``gripper`` in [0, 1], ``time`` (when the client took the target, in seconds on its own clock:
the stream's pace is fitted to these, not to when the puts came) and, on a session's first
put, ``deadman`` in [0.05, 1] s. Anything else
is refused whole (:class:`BadRequest` naming the field): a malformed put never moves the arm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import orjson

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.types import FloatArray

from .protocol import APPROACH, JOINTS, PITCH, POINT, Num, Obj, Vec, Word, check

TRACK_BYTES = 4096  # [bytes] a put, at most (one with six joints is under 300): larger is refused unread
MAX_SEQ = 2**53  # (a JSON number exact in every language)
DEADMAN = 0.25  # [s] the default: no put for this long and the arm brakes to rest
DEADMAN_RANGE = (0.05, 1.0)  # [s]
MAX_JOG = 1.0  # [m/s] a jogging velocity's components, at most (the limits slow it further)
MAX_JOG_RATE = 10.0  # [rad/s] a jogging pitch or roll rate, at most
MIN_SPEED = 1e-3  # the slowest fraction of the limits a stream takes (slower: a plan)
MODES = ("joints", "target", "velocity")
MAX_TIME = 1e9  # [s] a put's own time stamp, on the client's clock (any origin)

TRACK = Obj(
    {
        "session": Word(),
        "seq": Num("", 0, MAX_SEQ),
        "joints": JOINTS,
        "target": POINT,
        "approach": APPROACH,
        "roll": PITCH,
        "orientation": Vec(4, "", 1.0),  # (refused below until an arm takes it: a clear word, not "unknown")
        "velocity": Vec(3, "m/s", MAX_JOG),
        "pitch_rate": Num("rad/s", -MAX_JOG_RATE, MAX_JOG_RATE),
        "roll_rate": Num("rad/s", -MAX_JOG_RATE, MAX_JOG_RATE),
        "speed": Num("", 0.0, 1.0),
        "gripper": Num("", 0.0, 1.0),
        "deadman": Num("s", *DEADMAN_RANGE),
        "time": Num("s", -MAX_TIME, MAX_TIME),
    },
    required=(("session", "the stream's id (a string)"), ("seq", "its put's number (rising)")),
    exclusive=(
        ("joints", "target", "a put is one of joints, target or velocity"),
        ("joints", "velocity", "a put is one of joints, target or velocity"),
        ("target", "velocity", "a put is one of joints, target or velocity"),
    ),
    one_of=MODES,
    top=True,
)


@dataclass(frozen=True)
class TrackPut:
    session: str
    seq: int
    mode: str  # "joints", "target" or "velocity"
    value: FloatArray  # the joints [rad], target [m] or velocity [m/s]
    approach: object = None  # (a target's, as ik takes it)
    roll: float | None = None
    pitch_rate: float = 0.0
    roll_rate: float = 0.0
    speed: float | None = None
    gripper: float | None = None
    deadman: float | None = None
    time: float | None = None  # [s] when the client took the target, on its own clock: the stream's pace


def session_of(payload: bytes) -> str | None:
    """The session a put names, if it can be read (a refused put's event names it)."""
    if len(payload) > TRACK_BYTES:
        return None
    try:
        session = orjson.loads(payload).get("session")
    except (orjson.JSONDecodeError, AttributeError):
        return None
    return session if isinstance(session, str) and 0 < len(session) <= 64 else None


def parse(arm: Robot, payload: bytes) -> TrackPut:
    """The put, checked whole, or :class:`BadRequest` naming the first field that is wrong."""
    if len(payload) > TRACK_BYTES:
        raise BadRequest(f"a track put has at most {TRACK_BYTES} bytes, this one {len(payload)}", field="payload")
    try:
        obj = orjson.loads(payload)
    except orjson.JSONDecodeError as e:
        raise BadRequest(f"the put is not valid JSON: {e}", field="payload") from None
    if not isinstance(obj, dict):
        raise BadRequest(f"a track put is a JSON object, got {type(obj).__name__}", field="payload")
    seq = obj.get("seq")
    if seq is not None and (type(seq) is not int or not 0 <= seq <= MAX_SEQ):
        raise BadRequest(f"seq must be a whole number in [0, 2^53], got {str(seq)[:40]}", field="seq")
    msg = check(TRACK, obj, arm.joint_names)
    mode = next(m for m in MODES if m in msg)
    if "orientation" in msg:
        raise BadRequest(
            f"{arm.name} takes a target's position, approach and roll, not a whole orientation (yet)",
            field="orientation",
        )
    for name, what in (
        ("approach", "target"),
        ("roll", "target"),
        ("pitch_rate", "velocity"),
        ("roll_rate", "velocity"),
    ):
        if name in msg and mode != what:
            raise BadRequest(f"{name} goes with {what}, not {mode}", field=name)
    if ("roll" in msg or msg.get("roll_rate")) and arm.roll_joint is None:
        raise BadRequest(f"{arm.name} has no wrist roll", field="roll" if "roll" in msg else "roll_rate")
    if msg.get("pitch_rate") and not arm.chooses_pitch:
        raise BadRequest(f"{arm.name} has no wrist pitch", field="pitch_rate")
    speed = msg.get("speed")
    if speed is not None and speed < MIN_SPEED:
        raise BadRequest(f"speed must be in [{MIN_SPEED:g}, 1], got {speed!r}", field="speed")
    if "gripper" in msg and arm.gripper is None:
        raise BadRequest(f"{arm.name} has no gripper", field="gripper")
    value = np.array(msg[mode], dtype=float)
    if not np.all(np.isfinite(value)):  # (checked by the shape already: kept as a last word)
        raise BadRequest(f"{mode} must be finite numbers", field=mode)
    roll = msg.get("roll")
    return TrackPut(
        session=msg["session"],
        seq=int(obj["seq"]),
        mode=mode,
        value=value,
        approach=msg.get("approach"),
        roll=None if roll is None else float(roll),
        pitch_rate=float(msg.get("pitch_rate", 0.0)),
        roll_rate=float(msg.get("roll_rate", 0.0)),
        speed=None if speed is None else float(speed),
        gripper=None if "gripper" not in msg else float(msg["gripper"]),
        deadman=None if "deadman" not in msg else float(msg["deadman"]),
        time=None if "time" not in msg else float(msg["time"]),
    )


__all__ = ["DEADMAN", "TRACK_BYTES", "TrackPut", "parse", "session_of"]
