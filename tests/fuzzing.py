"""Generators of bad requests for the fuzz test (tests/test_fuzz.py) and bench/fuzz.py.

Every request produced is invalid in some way: not JSON, not an object, a wrong type or
length, NaN or infinities, unknown fields, robots or verbs, deep nesting, huge numbers, an
oversized payload, batch or trajectory, a speed too low to time, a bad deadline. Each must
get exactly one structured error reply.
"""

from __future__ import annotations

import json
import random
from collections.abc import Iterator

ROBOT = "insomniac"
NQ = 5
VERBS = ["info", "fk", "ik", "plan", "move", "stop", "gripper"]

_WRONG_VALUES: list[object] = ["x", "", None, True, {}, [], [[1, 2, 3]], {"a": 1}, "1.0", [None, None, None],
                               ["a", "b", "c"], [1, 2], [1, 2, 3, 4, 5, 6, 7, 8], 1e308, -1e308, 10**30]


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
        return "{\"target\": [0.2, 0.0, 0.1], \"note\": \"\u00e9\"}".encode("latin-1")  # not UTF-8
    return b'{"target": [0.2, 0.0, 0.1], "' + rng.choice([b"aproach", b"seeds", b"q", b"speedy"]) + b'": 1}'


_NOT_NULL = [v for v in _WRONG_VALUES if v is not None]  # null means "absent" for optional fields
_NOT_POINTS = [v for v in _NOT_NULL if v != [[1, 2, 3]]]  # a list of one point is a valid batch


def _verb_bad(rng: random.Random, verb: str) -> bytes:
    wrong = rng.choice(_WRONG_VALUES)
    opt = rng.choice(_NOT_NULL)
    if verb == "fk":
        req: dict[str, object] = {"q": wrong}
    elif verb == "ik":
        req = rng.choice([{"target": wrong}, {"target": [0.2, 0.0, 0.1], "approach": rng.choice(["up", 7.0, opt])},
                          {"target": [0.2, 0.0, 0.1], "seed": opt}, {"target": [0.2, 0.0, 0.1], "tolerance": opt},
                          {"targets": rng.choice(_NOT_POINTS)}, {"targets": [[0.2, 0.0, 0.1], wrong]}, {}])
    elif verb in ("plan", "move"):
        req = rng.choice([{"goal": wrong}, {"goal": [0.0] * NQ, "speed": rng.choice([0, -1, 2, 1e-7, opt])},
                          {"goal": [0.0, 1.0, -1.0, 0.0, 0.0], "speed": 0.001, "rate_hz": 1000},  # 10^6 samples
                          {"goal": [0.0] * NQ, "path": rng.choice(["curve", opt])},
                          {"goal": [0.0] * NQ, "rate_hz": rng.choice([0, 1e6, opt])},
                          {"goal": [9.0] * NQ}, {"goal": {"target": wrong}}, {"goal": [0.0] * NQ, "via": opt},
                          {}])
    elif verb == "gripper":
        req = {"opening": rng.choice([2.0, -1.0, wrong])}
    else:  # info, stop take nothing
        req = {rng.choice(["q", "x", "target"]): wrong}
    if req == {} and verb in ("info", "stop"):
        req = {"x": 1}
    if rng.random() < 0.1:  # the envelope: a deadline that is not a number of seconds > 0 (null: absent)
        req["deadline"] = rng.choice([0, -1, "soon", True, [], {}, None])
    return json.dumps(req).encode()


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
        else:
            verb = rng.choice(VERBS)
            yield f"{ROBOT}/{verb}", _verb_bad(rng, verb)
