"""Strict request validation (issue 14, item 7), against a real service over Zenoh: every
malformed request is ``bad_request`` naming the field by its path, never ``internal``, never
silently accepted; and the shapes' own rules, in-process."""

from __future__ import annotations

import json
from typing import Any

import pytest

from armd.clients import ArmClient
from armd.errors import BadRequest
from armd.planning.plan import PATHS
from armd.service.protocol import APPROACH_WORDS, FK, IK_ONE, PATH_WORDS, PLAN, check, real
from armd.solvers.target import APPROACHES

Q = [0.0, 1.2, -1.0, 0.0, 0.0]  # insomniac, within its limits
NEUTRAL = [0.0, 1.5707963267948966, -1.5707963267948966, 0.0, 0.0]
N = json.dumps(NEUTRAL)
HUGE_INT = "1" + "0" * 30  # a JSON integer beyond 64 bits (parsed as a double, 1e30)

# (verb on insomniac, raw JSON payload, the field the refusal names)
REFUSED = [
    # were internal
    ("ik", '{"targets": [[0.2, 0, 0.1]], "approach": [{"a": 1}]}', "approach[0]"),
    ("ik", '{"targets": [[0.2, 0, 0.1]], "approach": ["parallel"]}', "approach[0]"),
    ("ik", '{"targets": [[0.2, 0, 0.1]], "seeds": {"a": 1}}', "seeds"),
    ("ik", '{"targets": [[0.2, 0, 0.1]], "seeds": [[0, 1, -1, 0, {}]]}', "seeds[0][4]"),
    ("ik", '{"targets": [[1e308, 0, 0]]}', "targets[0][0]"),  # held a worker 9 s past its deadline
    ("plan", '{"goal": {"target": [1e308, 0, 0]}, "path": "line"}', "goal.target[0]"),  # OverflowError
    ("plan", '{"goal": {"target": [1e15, 0, 0]}, "path": "line"}', "goal.target[0]"),  # MemoryError
    ("plan", '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "speed": 1e-300}', "speed"),  # Ruckig: zero limits
    ("plan", '{"goal": {"target": [0.2, 0, 0.1]}, "path": "line", "speed": 1e-300}', "speed"),
    ("move", '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "speed": 1e-300}', "speed"),
    # were silently accepted
    (
        "plan",
        '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "start": {"position": ' + N + ', "jerk": [0, 0, 0, 0, 0]}}',
        "start.jerk",
    ),
    ("plan", '{"goal": {"target": [0.2, 0, 0.1], "q": [0.3, 1.4, -1.2, 0.2, 0]}}', "goal.q"),
    ("plan", '{"goal": {"q": [0.3, 1.4, -1.2, 0.2, 0], "approach": "free"}}', "goal.approach"),
    ("plan", '{"goal": {"q": [0.3, 1.4, -1.2, 0.2, 0], "zz": 1}}', "goal.zz"),
    ("plan", '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "via": [{"q": [0, 1.2, -1, 0, 0], "x": 1}]}', "via[0].x"),
    ("plan", '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "start": [true, 1.5, -1.5, 0, 0]}', "start[0]"),
    (
        "plan",
        '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "start": {"position": ' + N + ', "velocity": [false, 0, 0, 0, 0]}}',
        "start.velocity[0]",
    ),
    ("ik", '{"target": {"sensor": "et_left", "range": 0.1, "extra": 1}}', "target.extra"),
    ("ik", '{"target": {"sensor": 5, "range": 0.1}}', "target.sensor"),
    ("ik", '{"target": [true, 0, 0]}', "target[0]"),
    ("ik", '{"target": [0.2, 0, 0.1], "seed": [true, 1, -1, 0, 0]}', "seed[0]"),
    ("ik", '{"target": [0.2, 0, 0.1], "seed": [1e300, 1, -1, 0, 0]}', "seed[0]"),
    ("ik", '{"targets": [[true, 0, 0]]}', "targets[0][0]"),
    ("ik", '{"targets": [[0.2, 0, 0.1]], "approach": [true]}', "approach[0]"),
    ("ik", '{"targets": [[0.2, 0, 0.1]], "seeds": [true, 1, -1, 0, 0]}', "seeds[0]"),
    ("ik", '{"targets": [[0.2, 0, 0.1]], "target": [0.2, 0, 0.1]}', "target"),
    ("fk", '{"q": [true, false, 0, 0, 0]}', "q[0]"),
    ("fk", '{"q": [0, 1.2, -1, 0, true]}', "q[4]"),
    ("fk", '{"q": [1e300, 1.2, -1, 0, 0]}', "q[0]"),
    ("fk", '{"q": [' + HUGE_INT + ", 1.2, -1, 0, 0]}", "q[0]"),
    ("fk", '{"q": [18446744073709551616, 1.2, -1, 0, 0]}', "q[0]"),
    ("gripper", '{"opening": "0.5"}', "opening"),
    ("gripper", '{"opening": true}', "opening"),
    ("gripper", '{"opening": [0.5]}', "opening"),
]


def raw(client: ArmClient, key: str, payload: str) -> tuple[str, dict[str, Any]]:
    replies = list(client.session.get(f"armd/{key}", payload=payload.encode(), timeout=10.0))
    assert len(replies) == 1
    r = replies[0]
    if r.ok is not None:
        return "ok", json.loads(r.ok.payload.to_bytes())
    assert r.err is not None
    return "err", json.loads(r.err.payload.to_bytes())


@pytest.mark.parametrize(("verb", "payload", "field"), REFUSED)
def test_refused_naming_the_field(client: ArmClient, verb: str, payload: str, field: str) -> None:
    kind, reply = raw(client, f"insomniac/{verb}", payload)
    assert kind == "err" and reply["code"] == "bad_request", reply
    assert reply["field"] == field and field.split("[")[0].split(".")[-1] in reply["message"], reply


@pytest.mark.parametrize(
    ("verb", "payload"),
    [
        ("fk", '{"q": [0, 1.2, -1, 0, 0], "protocol": null}'),  # null is absent, the protocol too
        ("ik", '{"target": {"sensor": "et_left", "range": 0.1, "bearing": null}}'),  # at every level
        ("ik", '{"target": [0.25, 0.05, 0.12], "targets": null}'),
        (
            "plan",
            '{"goal": {"target": [0.25, 0.05, 0.15], "approach": null}, "start": {"position": '
            + N
            + ', "velocity": null}}',
        ),
        ("plan", '{"goal": [0.3, 1.4, -1.2, 0.2, 0], "speed": 1e-6}'),  # the floor: Ruckig's refusal, not the shape's
        ("fk", '{"q": [0, 1.2, -1, 0, 1e-300]}'),  # tiny is a number
    ],
)
def test_valid_shapes_are_not_refused_by_the_shape(client: ArmClient, verb: str, payload: str) -> None:
    kind, reply = raw(client, f"insomniac/{verb}", payload)
    assert kind == "ok" or (reply["code"] != "internal" and "must be" not in reply["message"]), reply
    if verb != "plan" or "1e-6" not in payload:
        assert kind == "ok", reply


def test_unknown_key_messages_name_the_path_and_what_is_known() -> None:
    with pytest.raises(BadRequest) as e:
        check(PLAN, {"goal": Q, "start": {"position": NEUTRAL, "jerk": [0] * 5}}, ("a", "b", "c", "d", "e"))
    assert e.value.field == "start.jerk" and "position, velocity, acceleration" in e.value.message
    with pytest.raises(BadRequest) as e:
        check(IK_ONE, {"target": [0.2, 0.0, 0.1], "aproach": "free"})
    assert e.value.field == "aproach" and "this verb takes: target, approach" in e.value.message


def test_joint_vectors_have_one_value_per_joint() -> None:
    joints = ("yaw", "shoulder", "elbow")
    assert check(FK, {"q": [0, 1, -1]}, joints) == {"q": [0, 1, -1]}
    with pytest.raises(BadRequest) as e:
        check(FK, {"q": [0, 1]}, joints)
    assert e.value.field == "q" and "yaw, shoulder, elbow" in e.value.message


@pytest.mark.parametrize(
    "v", [True, False, "1", None, [], {}, float("nan"), float("inf"), -float("inf"), 10**400, -(10**400), 10**30, 1e300]
)
def test_real_refuses_what_is_not_a_finite_json_number_in_range(v: object) -> None:
    with pytest.raises(BadRequest) as e:
        real(v, "x.y", -100.0, 100.0)
    assert e.value.field == "x.y"


def test_real_accepts_numbers_and_integers_as_floats() -> None:
    assert real(3, "x") == 3.0 and type(real(3, "x")) is float
    assert real(-0.0, "x") == 0.0 and real(5e-324, "x") == 5e-324
    assert real(2**64, "x") == float(2**64)  # within a double's range, no bounds: a number
    with pytest.raises(BadRequest):
        real(10**400, "x")  # beyond a double: refused, not an OverflowError


def test_the_protocols_words_are_the_solvers_and_planners() -> None:
    assert APPROACH_WORDS == APPROACHES and PATH_WORDS == PATHS


def test_null_is_absent_at_every_level() -> None:
    out = check(PLAN, {"goal": {"target": [0.2, 0.0, 0.1], "approach": None}, "speed": None}, ("a", "b", "c", "d", "e"))
    assert out == {"goal": {"target": [0.2, 0.0, 0.1]}}
