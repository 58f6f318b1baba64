"""Operator limits through a real service over Zenoh: payload size, batch size, JSON depth,
waypoints, trajectory samples, and the per-request deadline (the operator's, and a shorter
one a request asks for). Each refused request gets one structured error and changes nothing."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
import zenoh

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import BadRequest, ServiceError
from armd.service.protocol import Limits
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import wait_for

ARM = "gupta3"
SLOW_ARM = "insomniac"  # its closest points at an asked pitch are iterated, not enumerated: slow work


@dataclass
class Served:
    """A service with its own prefix and limits, a simulated arm, and what is published."""

    service: Service
    sim: SimAdapter
    session: zenoh.Session
    prefix: str
    published: list[dict[str, Any]] = field(default_factory=list)
    stops: list[dict[str, Any]] = field(default_factory=list)  # what the service put on estop

    def ask(
        self, verb: str, req: dict[str, Any] | bytes, timeout: float = 30.0, arm: str = ARM
    ) -> tuple[str, dict[str, Any]]:
        """('ok' | 'err', reply object); exactly one reply is expected."""
        payload = req if isinstance(req, bytes) else json.dumps(req).encode()
        replies = list(self.session.get(f"{self.prefix}/{arm}/{verb}", payload=payload, timeout=timeout))
        assert len(replies) == 1, f"{len(replies)} replies"
        r = replies[0]
        if r.ok is not None:
            return "ok", json.loads(r.ok.payload.to_bytes())
        assert r.err is not None
        return "err", json.loads(r.err.payload.to_bytes())


@pytest.fixture(scope="module")
def served(router: str) -> Iterator[Any]:
    """make(prefix, limits, workers): a service on the module's router; all closed at the end."""
    opened: list[tuple[zenoh.Session, Service, SimAdapter, list[Any]]] = []

    def make(prefix: str, limits: Limits, workers: int = 4) -> Served:
        arm = robots.load(ARM)
        session = zenoh.open(network_config(connect=[router]))
        service = Service(
            session, {ARM: arm, SLOW_ARM: robots.load(SLOW_ARM)}, prefix=prefix, limits=limits, workers=workers
        )
        sim = SimAdapter(session, arm, prefix=prefix, time_scale=20.0)
        s = Served(service, sim, session, prefix)
        lock = threading.Lock()

        def on(sample: zenoh.Sample) -> None:
            with lock:
                into = s.stops if str(sample.key_expr).endswith("/estop") else s.published
                into.append(json.loads(sample.payload.to_bytes()))

        sub = session.declare_subscriber(f"{prefix}/{ARM}/trajectory", on)
        estops = session.declare_subscriber(f"{prefix}/{ARM}/estop", on)
        opened.append((session, service, sim, [sub, estops]))
        wait_for(lambda: service._adapter_count(arm) == 1, what="the simulated arm")
        return s

    yield make
    for session, service, sim, subs in opened:
        for sub in subs:
            sub.undeclare()
        sim.close()
        service.close()
        session.close()


@pytest.fixture(scope="module")
def tight(served: Any) -> Served:
    s: Served = served(
        "tight", Limits(max_payload_bytes=4000, max_batch=5, max_depth=4, max_waypoints=2, max_samples=500)
    )
    return s


@pytest.fixture(scope="module")
def slow(served: Any) -> Served:
    """One worker, a 1 s deadline, and room for requests that take far longer than that."""
    s: Served = served(
        "slow", Limits(max_payload_bytes=3_000_000, max_batch=50_000, max_samples=1_000_000, deadline=1.0), workers=1
    )
    return s


def unreachable_batch(n: int) -> dict[str, Any]:
    """n targets for SLOW_ARM, far above and below its base, a hair off the yaw axis, the tool
    asked to point down: each is answered by the closest-point iteration with the pitch task
    (~1-2 ms here), so n = 20,000 is tens of seconds of work."""
    rng = np.random.default_rng(3)
    off = 10.0 ** rng.uniform(-6, -3, size=n)
    angle = rng.uniform(-np.pi, np.pi, size=n)
    z = rng.choice([-1.0, 1.0], size=n) * rng.uniform(0.5, 0.8, size=n)
    return {
        "targets": np.round(np.column_stack([off * np.cos(angle), off * np.sin(angle), z]), 9).tolist(),
        "approach": "perpendicular",
    }


def test_limits_refuse_nonsense() -> None:
    for bad in (
        {"max_batch": 0},
        {"max_payload_bytes": -1},
        {"max_samples": 2.5},
        {"deadline": 0.0},
        {"deadline": float("nan")},
        {"deadline": True},
    ):
        with pytest.raises(BadRequest) as e:
            Limits(**bad)  # type: ignore[arg-type]
        assert e.value.field == next(iter(bad)) or e.value.field == "deadline"


def test_payload_limit(tight: Served) -> None:
    big = json.dumps({"q": [0, 1, -1], "note": "x" * 4000}).encode()
    kind, r = tight.ask("fk", big)
    assert kind == "err" and r["code"] == "too_large" and r["limit"] == 4000 and r["size"] == len(big)
    assert tight.ask("fk", {"q": [0, 1, -1]})[0] == "ok"


def test_batch_limit(tight: Served) -> None:
    arm = robots.load(ARM)
    points = [arm.fk([0.1 * k, 1.0, -1.0]).tolist() for k in range(6)]
    kind, r = tight.ask("ik", {"targets": points})
    assert kind == "err" and r["code"] == "too_large" and (r["size"], r["limit"]) == (6, 5) and r["field"] == "targets"
    kind, r = tight.ask("ik", {"targets": points[:5]})
    assert kind == "ok" and r["status"] == ["ok"] * 5


def test_depth_limit(tight: Served) -> None:
    kind, r = tight.ask("plan", {"goal": {"target": [[[[0.2]]], 0.0, 0.1]}})
    assert kind == "err" and r["code"] == "bad_request" and "deeper than 4" in r["message"]
    assert tight.ask("plan", {"goal": {"target": [0.2, 0.05, 0.1]}})[0] == "ok"


def test_waypoint_limit(tight: Served) -> None:
    via = [[0.1, 1.0, -1.0], [0.2, 1.0, -1.0], [0.3, 1.0, -1.0]]
    kind, r = tight.ask("plan", {"goal": [0.4, 1.0, -1.0], "via": via})
    assert kind == "err" and r["code"] == "bad_request" and r["field"] == "via"
    assert tight.ask("plan", {"goal": [0.4, 1.0, -1.0], "via": via[:2]})[0] == "ok"


def test_sample_limit(tight: Served) -> None:
    goal = [0.5, 1.2, -1.2]
    kind, r = tight.ask("plan", {"goal": goal, "rate_hz": 1000})
    assert kind == "err" and r["code"] == "too_large" and r["limit"] == 500 and r["size"] > 500
    before = len(tight.published)
    kind, r = tight.ask("move", {"goal": goal, "rate_hz": 1000})
    assert kind == "err" and r["code"] == "too_large"
    time.sleep(0.3)
    assert len(tight.published) == before  # refused: nothing sent to the arm
    kind, r = tight.ask("plan", {"goal": goal, "rate_hz": 20})
    assert kind == "ok" and len(r["times"]) <= 500


def test_a_speed_too_low_to_time_is_a_bad_request(tight: Served) -> None:
    kind, r = tight.ask("plan", {"goal": [0.5, 1.2, -1.2], "speed": 1e-7})  # Ruckig's own range ends
    assert kind == "err" and r["code"] == "bad_request" and r["field"] == "speed"


def test_a_request_may_ask_for_a_deadline(tight: Served) -> None:
    for bad in (-1, 0, "soon", True, [1]):
        kind, r = tight.ask("fk", {"q": [0, 1, -1], "deadline": bad})
        assert kind == "err" and r["code"] == "bad_request" and r["field"] == "deadline", bad
    assert tight.ask("fk", {"q": [0, 1, -1], "deadline": None})[0] == "ok"
    assert tight.ask("fk", {"q": [0, 1, -1], "deadline": 5})[0] == "ok"
    # a deadline no request can meet: it passes while the request is handed to a worker
    kind, r = tight.ask("fk", {"q": [0, 1, -1], "deadline": 1e-9})
    assert kind == "err" and r["code"] == "deadline" and r["stage"] == "queued" and r["deadline"] == 1e-9


def test_arm_client_sends_its_deadline(router: str, tight: Served) -> None:
    with ArmClient(router, prefix="tight", deadline=1e-9) as c:
        with pytest.raises(ServiceError) as e:
            c.fk(ARM, [0, 1, -1])
        assert e.value.code == "deadline" and e.value.fields["stage"] == "queued"
        assert c.call(f"{ARM}/fk", {"q": [0, 1, -1]}, deadline=5.0)["within_limits"]  # one call's own deadline


def test_stop_is_never_refused_for_lateness(tight: Served) -> None:
    before = len(tight.stops)
    kind, r = tight.ask("stop", {"deadline": 1e-9})
    assert kind == "ok", r
    wait_for(lambda: len(tight.stops) > before, what="the estop")
    assert tight.stops[-1]["id"] == r["id"]


def test_work_that_overruns_its_deadline_is_abandoned(slow: Served) -> None:
    # an IK batch of ~10 s of work, under a 1 s deadline (a request asking for 100 s gets the operator's 1 s)
    kind, r = slow.ask("ik", {**unreachable_batch(20_000), "deadline": 100}, arm=SLOW_ARM)
    assert kind == "err" and r["code"] == "deadline" and r["stage"] == "working", r
    assert r["deadline"] == 1.0 and r["elapsed"] >= 1.0
    # a line move whose planning (~1.5 s: 180,000 samples) overruns the 0.1 s its client allows: nothing published
    start = slow.sim.position.copy()
    goal = (robots.load(ARM).fk(start) + np.array([0.0, 0.05, 0.05])).tolist()
    before = len(slow.published)
    kind, r = slow.ask(
        "move", {"goal": {"target": goal}, "path": "line", "speed": 0.02, "rate_hz": 1000, "deadline": 0.1}
    )
    assert kind == "err" and r["code"] == "deadline" and r["stage"] == "working", r
    time.sleep(0.3)
    assert len(slow.published) == before and np.array_equal(slow.sim.position, start)
    # the same move with time to plan it moves the arm
    kind, r = slow.ask("move", {"goal": {"target": goal}, "path": "line", "speed": 0.5})
    assert kind == "ok", r
    wait_for(lambda: len(slow.published) > before, what="the trajectory")
    assert slow.published[-1]["id"] == r["id"]
    wait_for(lambda: slow.service.stats()["in_flight"] == 0, what="an idle service")  # (counted down after the reply)


def test_a_request_queued_past_its_deadline_is_not_worked_on(slow: Served) -> None:
    wait_for(lambda: slow.service.stats()["in_flight"] == 0, what="earlier requests answered")
    time.sleep(0.2)  # (and counted: a request is counted just after its reply)
    late_before = slow.service.stats()["late"]
    busy = slow.session.get(
        f"{slow.prefix}/{SLOW_ARM}/ik", payload=json.dumps(unreachable_batch(20_000)).encode(), timeout=30.0
    )  # occupies the one worker until its 1 s deadline
    wait_for(lambda: slow.service.stats()["in_flight"] >= 1, what="the batch to arrive")
    # a joint plan (fk and one-target IK are answered at once, without queueing) waits behind it, past its 0.2 s
    kind, r = slow.ask("plan", {"goal": [0.5, 1.0, -1.0], "start": [0, 1, -1], "deadline": 0.2})
    assert kind == "err" and r["code"] == "deadline" and r["stage"] == "queued", r
    kind, r = slow.ask("fk", {"q": [0, 1, -1], "deadline": 0.2})  # behind the same busy worker: not queued
    assert kind == "ok", r
    replies = list(busy)
    assert len(replies) == 1 and replies[0].err is not None
    assert json.loads(replies[0].err.payload.to_bytes())["stage"] == "working"
    assert slow.ask("fk", {"q": [0, 1, -1]})[0] == "ok"  # and then it serves as before
    assert slow.service.stats()["late"] == late_before + 2


def test_stop_does_not_wait_behind_the_queue(slow: Served) -> None:
    """The one worker is busy for a second and more requests queue behind it: a stop is
    answered (and published) while the busy request is still being worked on."""
    busy = slow.session.get(
        f"{slow.prefix}/{SLOW_ARM}/ik", payload=json.dumps(unreachable_batch(20_000)).encode(), timeout=30.0
    )
    wait_for(lambda: slow.service.stats()["in_flight"] >= 1, what="the batch to arrive")
    queued = [slow.session.get(f"{slow.prefix}/{ARM}/fk", payload=b'{"q": [0, 1, -1]}', timeout=30.0) for _ in range(3)]
    before = len(slow.stops)
    kind, r = slow.ask("stop", {})
    assert kind == "ok", r
    assert busy.try_recv() is None  # the batch has not been answered yet: the stop did not wait for it
    wait_for(lambda: len(slow.stops) > before, what="the estop")
    assert slow.stops[-1]["id"] == r["id"]
    assert len(list(busy)) == 1 and all(len(list(q)) == 1 for q in queued)
    wait_for(lambda: slow.service.stats()["in_flight"] == 0, what="an idle service")
