"""The JSON protocol (version 1): request validation and reply shapes, independent of Zenoh.

Every request is a JSON object; every reply is a JSON object. A bad request raises
:class:`robots.BadRequest` naming the ``field``; the service turns any
:class:`robots.ArmdError` into an error reply ``{"code", "message", ...}`` in one place.
The full description, with a JSON Schema per verb, is ``docs/protocol.md``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import orjson

from robots import ArmdError, BadRequest

PROTOCOL_VERSION = 1
VERBS = ("info", "fk", "ik", "plan", "move", "stop", "gripper")
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
    if payload.count(b"[") + payload.count(b"{") >= limits.max_depth and _depth(obj, 1) > limits.max_depth:
        raise BadRequest(f"the request is nested deeper than {limits.max_depth} levels", field="payload")
    version = obj.get("protocol", PROTOCOL_VERSION)
    if version != PROTOCOL_VERSION or isinstance(version, bool):
        raise BadRequest(f"protocol version {version!r} is not spoken here; this service speaks {PROTOCOL_VERSION}",
                         field="protocol")
    return obj


def _depth(obj: object, level: int) -> int:
    """Nesting depth of parsed JSON (a scalar inside a container is one level deeper)."""
    values = obj.values() if isinstance(obj, dict) else obj
    deepest = level
    for v in values:  # type: ignore[attr-defined]
        if isinstance(v, (dict, list)):
            d = _depth(v, level + 1)
            if d > deepest:
                deepest = d
        elif deepest == level:
            deepest = level + 1
    return deepest


class PayloadTooLarge(ArmdError):
    code = "too_large"

    def __init__(self, size: int, limit: int) -> None:
        super().__init__(f"the payload is {size} bytes; this service accepts at most {limit}", size=size, limit=limit)


class UnknownVerb(ArmdError):
    code = "unknown_verb"

    def __init__(self, verb: str) -> None:
        super().__init__(f"unknown verb {verb!r}; verbs: {', '.join(VERBS)}", verb=verb, verbs=list(VERBS))


class NoAdapter(ArmdError):
    code = "no_adapter"


class Rejected(ArmdError):
    """Every live adapter of the arm refused the trajectory (``reason``: the last one's word)."""

    code = "rejected"


class Internal(ArmdError):
    code = "internal"


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
