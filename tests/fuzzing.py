"""Generators of bad requests for the fuzz test (tests/test_fuzz.py) and bench/fuzz.py.

Every request produced is invalid in some way: not JSON, not an object, a wrong type or
length, NaN or infinities, unknown fields, robots or verbs, deep nesting, huge numbers, an
oversized payload, batch or trajectory, a speed too low to time, a bad deadline. Each must
get exactly one structured error reply.

:func:`mutation` takes a valid request of every verb and breaks it in one place: an unknown
key in any of its objects, a boolean, string, list, object or huge number where a number
goes, a wrong type where a word goes, both of two fields that exclude each other. The field
the service must name is known: the path of the place broken (``start.velocity[2]``,
``goal.zz``). Its ``tiny`` mode puts a tiny number (1e-300, the smallest double) where a
number goes, which may well be valid: any answer but ``internal``. :func:`mutations` is the
same as a Hypothesis strategy (tests/test_fuzz.py); :func:`bad_requests` mixes it in.
"""

from __future__ import annotations

import json
import random
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NamedTuple, TypeVar

from hypothesis import strategies as st

ROBOT = "insomniac"
NQ = 5
VERBS = ["info", "fk", "ik", "plan", "move", "stop", "gripper"]

_WRONG_VALUES: list[object] = [
    "x",
    "",
    None,
    True,
    {},
    [],
    [[1, 2, 3]],
    {"a": 1},
    "1.0",
    [None, None, None],
    ["a", "b", "c"],
    [1, 2],
    [1, 2, 3, 4, 5, 6, 7, 8],
    1e308,
    -1e308,
    10**30,
]


def _raw_bad(rng: random.Random) -> bytes:
    kind = rng.randrange(9)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))  # noise
    if kind == 1:
        good = json.dumps({"target": [0.2, 0.0, 0.1]}).encode()
        return good[: rng.randrange(1, len(good) - 1)]  # truncated
    if kind == 2:
        return json.dumps(rng.choice([[1, 2, 3], "ik", 3.5, None, True])).encode()  # not an object
    if kind == 3:
        return b'{"target": [0.2, NaN, 0.1]}' if rng.random() < 0.5 else b'{"target": [Infinity, 0, 0]}'
    if kind == 4:
        return b'{"target": [1e999, 0, 0]}'
    if kind == 5:
        depth = rng.randrange(10, 200)
        return b'{"target": ' + b"[" * depth + b"]" * depth + b"}"  # deep nesting
    if kind == 6:
        return b'{"q": [0, 1, -1, 0, 0], "protocol": ' + str(rng.choice([0, 2, 99, '"1"'])).encode() + b"}"
    if kind == 7:
        return '{"target": [0.2, 0.0, 0.1], "note": "\u00e9"}'.encode("latin-1")  # not UTF-8
    return b'{"target": [0.2, 0.0, 0.1], "' + rng.choice([b"aproach", b"seeds", b"q", b"speedy"]) + b'": 1}'


_NOT_NULL = [v for v in _WRONG_VALUES if v is not None]  # null means "absent" for optional fields
_NOT_POINTS = [v for v in _NOT_NULL if v != [[1, 2, 3]]]  # a list of one point is a valid batch


def _verb_bad(rng: random.Random, verb: str) -> bytes:
    wrong = rng.choice(_WRONG_VALUES)
    opt = rng.choice(_NOT_NULL)
    if verb == "fk":
        req: dict[str, object] = {"q": wrong}
    elif verb == "ik":
        req = rng.choice(
            [
                {"target": wrong},
                {"target": [0.2, 0.0, 0.1], "approach": rng.choice(["up", 7.0, opt])},
                {"target": [0.2, 0.0, 0.1], "seed": opt},
                {"target": [0.2, 0.0, 0.1], "tolerance": opt},
                {"targets": rng.choice(_NOT_POINTS)},
                {"targets": [[0.2, 0.0, 0.1], wrong]},
                {},
            ]
        )
    elif verb in ("plan", "move"):
        req = rng.choice(
            [
                {"goal": wrong},
                {"goal": [0.0] * NQ, "speed": rng.choice([0, -1, 2, 1e-7, opt])},
                {"goal": [0.0, 1.0, -1.0, 0.0, 0.0], "speed": 0.001, "rate_hz": 1000},  # 10^6 samples
                {"goal": [0.0] * NQ, "path": rng.choice(["curve", opt])},
                {"goal": [0.0] * NQ, "rate_hz": rng.choice([0, 1e6, opt])},
                {"goal": [9.0] * NQ},
                {"goal": {"target": wrong}},
                {"goal": [0.0] * NQ, "via": opt},
                {},
            ]
        )
    elif verb == "gripper":
        req = {"opening": rng.choice([2.0, -1.0, wrong])}
    else:  # info, stop take nothing
        req = {rng.choice(["q", "x", "target"]): wrong}
    if req == {} and verb in ("info", "stop"):
        req = {"x": 1}
    if rng.random() < 0.1:  # the envelope: a deadline that is not a number of seconds > 0 (null: absent)
        req["deadline"] = rng.choice([0, -1, "soon", True, [], {}, None])
    return json.dumps(req).encode()


# -- one place broken in a valid request ------------------------------------------------------

_Q = [0.0, 1.2, -1.0, 0.0, 0.0]
_Q2 = [0.3, 1.4, -1.2, 0.2, 0.0]
_NEUTRAL = [0.0, 1.5707963267948966, -1.5707963267948966, 0.0, 0.0]
# (verb, a valid request, fields that exclude one already there: (path to the object, key, value,
# the field the refusal names))
Exclusive = tuple[tuple[str | int, ...], str, Any, str]
BASES: list[tuple[str, dict[str, Any], list[Exclusive]]] = [
    ("fk", {"q": _Q, "protocol": 1}, []),
    (
        "ik",
        {"target": [0.25, 0.05, 0.12], "approach": "perpendicular", "seed": _Q, "tolerance": 1e-6, "quantise": False},
        [((), "targets", [[0.25, 0.05, 0.12]], "target")],
    ),
    (
        "ik",
        {"target": {"sensor": "et_left", "range": 0.1, "bearing": 0.0}},
        [((), "targets", [[0.2, 0.0, 0.1]], "target")],
    ),
    (
        "ik",
        {
            "targets": [[0.25, 0.0, 0.2], [0.2, 0.1, 0.1]],
            "approach": [0.0, -0.5],
            "seeds": [_Q, _Q2],
            "tolerance": 1e-6,
        },
        [((), "target", [0.25, 0.0, 0.2], "target")],
    ),
    (
        "plan",
        {
            "goal": _Q2,
            "start": {"position": _NEUTRAL, "velocity": [0.0] * NQ, "acceleration": [0.0] * NQ},
            "speed": 0.5,
            "rate_hz": 50,
            "via": [_Q, {"q": _Q}],
        },
        [(("via", 1), "target", [0.2, 0.0, 0.1], "via[1].q"), (("via", 1), "approach", "free", "via[1].approach")],
    ),
    (
        "plan",
        {"goal": {"target": [0.25, 0.05, 0.15], "approach": "free"}, "path": "line", "start": _NEUTRAL},
        [(("goal",), "q", _Q, "goal.q")],
    ),
    (
        "move",
        {"goal": {"q": _Q2}, "speed": 0.5, "path": "joint"},
        [(("goal",), "target", [0.25, 0.05, 0.15], "goal.q"), (("goal",), "approach", "free", "goal.approach")],
    ),
    ("gripper", {"opening": 0.5}, []),
    ("info", {}, []),
    ("stop", {}, []),
]
NOT_NUMBERS: list[object] = [True, False, "0.5", "", [], [0.5], {}, {"a": 1}]
HUGE: list[object] = [1e308, -1e308, 1e30, 10**30, -(10**25), 1.7976931348623157e308, 18446744073709551616]
TINY: list[object] = [1e-300, -1e-300, 5e-324, -0.0, 0]
NOT_WORDS: list[object] = [True, [], {}, ["free"], {"free": 1}]
UNKNOWN_KEYS = ["zz", "jerk", "note", "Target", "q ", ""]


class Mutation(NamedTuple):
    """A request broken in one place: ``field`` is its path, what the error must name
    (``tiny``: a tiny number, maybe valid; any reply but internal will do)."""

    key: str
    request: dict[str, Any]
    field: str
    how: str
    tiny: bool = False


T = TypeVar("T")
Choose = Callable[[Sequence[T]], T]


def _leaves(obj: object, path: tuple[str | int, ...] = ()) -> Iterator[tuple[tuple[str | int, ...], object]]:
    yield path, obj
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaves(v, (*path, i))


def field_of(path: Sequence[str | int]) -> str:
    """``("start", "velocity", 2)`` -> ``start.velocity[2]``: how the service names a field."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _at(obj: Any, path: Sequence[str | int]) -> Any:
    for p in path:
        obj = obj[p]
    return obj


def mutation(choose: Choose[Any], *, tiny: bool = False) -> Mutation:
    """A valid request broken in one place, each choice made by ``choose`` (``rng.choice``, or
    a Hypothesis draw). ``tiny``: a tiny number in place of one, instead."""
    verb, base, exclusive = choose(BASES)
    req = json.loads(json.dumps(base))  # (not deepcopy: it keeps the bases' shared lists shared)
    leaves = list(_leaves(req))
    numbers = [p for p, v in leaves if type(v) in (int, float) and p]
    if tiny and numbers:
        path = choose(numbers)
        _at(req, path[:-1])[path[-1]] = choose(TINY)
        return Mutation(f"{ROBOT}/{verb}", req, field_of(path), "tiny", tiny=True)
    words = [p for p, v in leaves if type(v) is str]
    objects = [p for p, v in leaves if isinstance(v, dict)]
    kinds = (
        ["unknown key"]
        + ["not a number", "huge"] * bool(numbers)
        + ["not a word"] * bool(words)
        + ["both exclusive"] * bool(exclusive)
    )
    how = choose(kinds)
    if how == "unknown key":
        path = choose(objects)
        key = choose(UNKNOWN_KEYS)
        _at(req, path)[key] = choose([1, 0.5, "x", None, [], {}])
        return Mutation(f"{ROBOT}/{verb}", req, field_of((*path, key)), how)
    if how == "both exclusive":
        path, key, value, field = choose(exclusive)
        _at(req, path)[key] = value
        return Mutation(f"{ROBOT}/{verb}", req, field, how)
    path = choose(numbers if how != "not a word" else words)
    _at(req, path[:-1])[path[-1]] = choose({"not a number": NOT_NUMBERS, "huge": HUGE, "not a word": NOT_WORDS}[how])
    return Mutation(f"{ROBOT}/{verb}", req, field_of(path), how)


@st.composite
def mutations(draw: st.DrawFn, tiny: bool = False) -> Mutation:
    """:func:`mutation` as a Hypothesis strategy (each choice a draw, so failures shrink)."""
    return mutation(lambda seq: draw(st.sampled_from(seq)), tiny=tiny)


def bad_requests(n: int, seed: int = 0, *, oversized: int = 3) -> Iterator[tuple[str, bytes]]:
    """``n`` (key suffix, payload) pairs, every one invalid; ``oversized`` of them huge."""
    rng = random.Random(seed)
    for i in range(n):
        if i < oversized:
            yield f"{ROBOT}/ik", b'{"target": [0.2, 0.0, 0.1], "pad": "' + b"x" * 1_200_000 + b'"}'
            continue
        if i < 2 * oversized:
            yield f"{ROBOT}/ik", json.dumps({"targets": [[0.2, 0.0, 0.1]] * 10_001}).encode()
            continue
        r = rng.random()
        if r < 0.1:
            yield rng.choice(["nosuch/ik", "Insomniac/fk", f"{ROBOT}/dance", f"{ROBOT}/ik/x", f"{ROBOT}"]), b"{}"
        elif r < 0.4:
            yield f"{ROBOT}/{rng.choice(VERBS)}", _raw_bad(rng)
        elif r < 0.7:
            m = mutation(rng.choice)
            yield m.key, json.dumps(m.request).encode()
        else:
            verb = rng.choice(VERBS)
            yield f"{ROBOT}/{verb}", _verb_bad(rng, verb)
