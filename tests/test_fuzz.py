"""Fuzz: thousands of bad requests over Zenoh, each answered once with a structured error;
nothing published, memory bounded, and the service still right afterwards. Valid requests
broken in one place (tests/fuzzing.py's mutations, drawn by Hypothesis) are refused as
``bad_request`` naming the place; a tiny number in place of one is never ``internal``."""

from __future__ import annotations

import json
import resource
import time
from typing import Any

import numpy as np
from hypothesis import given, settings

from armd import robots, solvers
from armd.clients import ArmClient
from tests.fuzzing import Mutation, bad_requests, mutations

N = 2000  # the suite's share; bench/fuzz.py runs 10,000 and more


def test_bad_requests_each_get_one_structured_error(client: ArmClient, service: object) -> None:
    published: list[str] = []
    sub = client.session.declare_subscriber(
        "armd/**",
        lambda s: (
            published.append(str(s.key_expr))
            if s.key_expr.intersects("armd/*/trajectory") or s.key_expr.intersects("armd/*/gripper")
            else None
        ),
    )
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        codes: dict[str, int] = {}
        for i, (key, payload) in enumerate(bad_requests(N, seed=7)):
            replies = list(client.session.get(f"armd/{key}", payload=payload, timeout=10.0))
            assert len(replies) == 1, (i, key, payload[:80], len(replies))
            reply = replies[0]
            if reply.ok is not None and key.endswith("/stop"):  # (a stop is never refused: the arm stops,
                err = json.loads(reply.ok.payload.to_bytes())["unread"]  # and its reply says why the request
            else:  # was not read)
                assert reply.ok is None, (i, key, payload[:200], reply.ok.payload.to_bytes()[:200])
                assert reply.err is not None
                err = json.loads(reply.err.payload.to_bytes())
            assert isinstance(err.get("code"), str) and isinstance(err.get("message"), str) and err["message"], err
            codes[err["code"]] = codes.get(err["code"], 0) + 1
        time.sleep(0.2)
    finally:
        sub.undeclare()
    assert published == []  # no trajectory or gripper command for any of them
    assert set(codes) <= {"bad_request", "unknown_robot", "unknown_verb", "too_large", "no_adapter", "unreachable"}
    assert codes.get("internal", 0) == 0
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss_before) / 1024
    assert grown_mb < 200, f"resident memory grew by {grown_mb:.0f} MB"
    # and a valid request afterwards gets the right answer
    arm = robots.load("insomniac")
    target = arm.fk(np.array([0.3, 1.2, -1.0, -0.5, 0.0]))
    r = client.ik("insomniac", target.tolist())
    assert r.status == "ok" and np.allclose(r.q, solvers.solve_ik(arm, target).q, atol=1e-12)


def ask(client: ArmClient, m: Mutation) -> tuple[str, dict[str, Any]]:
    replies = list(client.session.get(f"armd/{m.key}", payload=json.dumps(m.request).encode(), timeout=10.0))
    assert len(replies) == 1, (m, len(replies))
    r = replies[0]
    if r.ok is not None:
        return "ok", json.loads(r.ok.payload.to_bytes())
    assert r.err is not None
    return "err", json.loads(r.err.payload.to_bytes())


@settings(max_examples=500, deadline=None)
@given(m=mutations())
def test_a_request_broken_in_one_place_is_refused_naming_the_place(client: ArmClient, m: Mutation) -> None:
    kind, reply = ask(client, m)
    if m.key.endswith("/stop"):  # (a stop is never refused: it stops, and says what it did not read)
        assert kind == "ok" and "stopped all the same" in reply["warning"], (m, reply)
        reply = reply["unread"]
    else:
        assert kind == "err", (m, reply)
    assert reply["code"] == "bad_request" and reply.get("field") == m.field and reply["message"], (m, reply)


@settings(max_examples=200, deadline=None)
@given(m=mutations(tiny=True))
def test_a_tiny_number_anywhere_is_never_internal(client: ArmClient, m: Mutation) -> None:
    kind, reply = ask(client, m)
    assert kind == "ok" or reply["code"] != "internal", (m, reply)


def test_still_serving_after_the_mutations(client: ArmClient, service: object) -> None:
    assert client.fk("insomniac", [0.0, 1.2, -1.0, 0.0, 0.0]).within_limits
    stats = service.stats()  # type: ignore[attr-defined]
    assert stats["in_flight"] == 0 and stats["served"] > 0
