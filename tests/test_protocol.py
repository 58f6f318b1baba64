"""Request decoding and field checks, in-process: what is refused, and with which message.

``decode`` leaves the UTF-8 check to orjson (asked which it was only when it refuses) and walks
a request for its depth only when it has enough brackets to be too deep: these check that the
refusals are the same as when both checks ran on every request.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armd.errors import BadRequest
from armd.service.protocol import IK_ONE, MAX_METRES, Limits, allowed, check, decode, plain_point

scalars = (
    st.none()
    | st.booleans()
    | st.integers(-(10**6), 10**6)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(alphabet='[]{}"\\ ab', max_size=6)
)
objects = st.dictionaries(
    st.text(alphabet="[]{}ab", max_size=3),
    st.recursive(
        scalars,
        lambda inner: (
            st.lists(inner, max_size=3) | st.dictionaries(st.text(alphabet="[]{ab", max_size=2), inner, max_size=3)
        ),
        max_leaves=12,
    ),
    max_size=3,
)


def depth(obj: object, level: int = 1) -> int:
    """The test's own reading of nesting depth (a scalar inside a container is one level deeper),
    written plainly and recursively: the service walks it another way."""
    values = list(obj.values()) if isinstance(obj, dict) else obj if isinstance(obj, list) else []
    return max((depth(v, level + 1) if isinstance(v, (dict, list)) else level + 1 for v in values), default=level)


def refusal(payload: bytes, limits: Limits) -> str | None:
    try:
        decode(payload, limits)
    except BadRequest as e:
        return str(e)
    return None


@settings(max_examples=400, deadline=None)
@given(obj=objects, max_depth=st.integers(1, 7))
def test_too_deep_exactly_when_nested_deeper_than_the_limit(obj: dict[str, Any], max_depth: int) -> None:
    payload = json.dumps(obj).encode()  # (brackets inside strings too: they only make the bound looser)
    why = refusal(payload, Limits(max_depth=max_depth))
    if depth(obj) > max_depth:
        assert why is not None and f"deeper than {max_depth}" in why
    else:
        assert why is None


@pytest.mark.parametrize(
    ("payload", "ok"),
    [
        (b'{"a": [[1]]}', True),  # depth 4 from 3 brackets: not walked, and within 4
        (b'{"a": [[[]]]}', True),  # 4 brackets, depth 4: walked, within
        (b'{"a": [[[1]]]}', False),  # depth 5
        (b'{"a": "[[[[[[[["}', True),  # brackets in a string: walked, depth 2
    ],
)
def test_depth_at_the_limit(payload: bytes, ok: bool) -> None:
    assert (refusal(payload, Limits(max_depth=4)) is None) == ok


@settings(max_examples=600, deadline=None)
@given(
    payload=st.binary(min_size=1, max_size=40)
    | objects.map(lambda o: json.dumps(o, ensure_ascii=False).encode())
    | st.builds(lambda a, b, c: a + b + c, st.just(b'{"a": "'), st.binary(max_size=8), st.just(b'"}'))
)
def test_not_utf8_and_not_json_are_told_apart(payload: bytes) -> None:
    why = refusal(payload, Limits())
    try:
        payload.decode("utf-8")
    except UnicodeDecodeError:
        assert why is not None and "not UTF-8" in why
        return
    assert why is None or "not UTF-8" not in why


def test_bom_and_bad_bytes_messages() -> None:
    assert "not UTF-8" in str(refusal(b"\xff\xfe", Limits()))
    assert "not UTF-8" in str(refusal(b'{"a": "\xed\xa0\x80"}', Limits()))  # a surrogate, encoded
    assert "not valid JSON" in str(refusal(b'\xef\xbb\xbf{"a": 1}', Limits()))  # UTF-8, but JSON has no BOM


def test_allowed_names_the_first_unknown_field() -> None:
    allowed({"target": [0, 0, 0], "deadline": 1, "protocol": 1}, "target", "seed")
    allowed({}, "target")
    with pytest.raises(BadRequest) as e:
        allowed({"target": 1, "zz": 2, "aproach": 3}, "target", "approach")
    assert e.value.fields["field"] == "aproach" and "this verb takes: target, approach" in str(e.value)
    with pytest.raises(BadRequest):  # a verb that takes nothing
        allowed({"q": 1})


coordinates = (
    st.floats(-MAX_METRES, MAX_METRES)
    | st.floats(allow_nan=False)
    | st.integers(-2, 2)
    | st.booleans()
    | st.none()
    | st.just(MAX_METRES)
    | st.just(-MAX_METRES)
)
ik_requests = st.dictionaries(
    st.sampled_from(["target", "deadline", "protocol", "approach", "seed", "targets", "x"]),
    st.lists(coordinates, min_size=2, max_size=4) | coordinates | st.just({"sensor": "et_left", "range": 0.2}),
    max_size=3,
)


@settings(max_examples=600, deadline=None)
@given(req=ik_requests | st.builds(lambda t: {"target": t}, st.lists(coordinates, min_size=3, max_size=3)))
def test_plain_point_is_what_the_full_check_passes_unchanged(req: dict[str, Any]) -> None:
    """Whatever the one-pass check takes, the full check of IK_ONE takes too, and leaves as it
    is; and it takes every plain point within bounds (else the fast path would be dead)."""
    point = plain_point(req)
    t = req.get("target")
    plain = (
        set(req) <= {"target", "deadline", "protocol"}
        and isinstance(t, list)
        and len(t) == 3
        and all(type(x) is float and abs(x) <= MAX_METRES for x in t)
    )
    assert (point is not None) == plain
    if point is not None:
        assert check(IK_ONE, req, ("a", "b", "c", "d", "e"))["target"] is point
