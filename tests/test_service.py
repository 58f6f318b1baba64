"""The service over real Zenoh sessions on 127.0.0.1: every verb, every error code, concurrency."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
import zenoh

from armd import robots, solvers
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import ArmdError, ServiceError
from tests.conftest import clear_configs, collect, wait_for
from tests.test_fk import random_in_limits

JSON = zenoh.Encoding.APPLICATION_JSON


def raw(client: ArmClient, key: str, payload: bytes) -> tuple[str, dict[str, object]]:
    """Send raw bytes; ('ok' | 'err', reply object). Exactly one reply is expected."""
    replies = list(client.session.get(f"armd/{key}", payload=payload, timeout=10.0))
    assert len(replies) == 1, f"{len(replies)} replies"
    r = replies[0]
    if r.ok is not None:
        return "ok", json.loads(r.ok.payload.to_bytes())
    assert r.err is not None
    return "err", json.loads(r.err.payload.to_bytes())


def test_robots_and_info(client: ArmClient) -> None:
    assert [r["name"] for r in client.robots()] == robots.names()
    info = client.info("desk4")
    assert info["coupled_limits"][0]["name"] == "linkage" and info["protocol"] == 1
    assert info["state"]["source"] in ("neutral", "commanded", "adapter")
    assert info["world"]["ground"] == 0.0 and ["gripper", "ground"] in info["world"]["pairs"]


def test_every_reply_names_the_service_that_gave_it(client: ArmClient, service: object) -> None:
    """An answer, an error of the request's, a bad key, an unknown robot: each names the
    replica (its id), so an operator can tell who answered."""
    me = service.id  # type: ignore[attr-defined]
    asks = [
        ("robots", b"{}", "ok"),
        ("desk4/info", b"{}", "ok"),
        ("sg5ut/fk", b'{"q": [0, 1, -0.5, -0.4]}', "ok"),
        ("sg5ut/fk", b'{"q": [true, 1, -0.5, -0.4]}', "err"),
        ("nosuch/ik", b'{"target": [0.2, 0, 0.1]}', "err"),
        ("desk4/nosuchverb", b"{}", "err"),
        ("desk4/ik", b"not json", "err"),
    ]
    for key, payload, kind in asks:
        got, reply = raw(client, key, payload)
        assert got == kind and reply["service"] == me, (key, reply)
    assert len(me) >= 8


def test_fk(client: ArmClient) -> None:
    arm = robots.load("sg5ut")
    q = [0.2, 1.0, -0.5, -0.4]
    r = client.fk("sg5ut", q)
    assert np.allclose(r.position, arm.fk(q), atol=1e-15) and r.within_limits


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "gupta3", "desk4"])
def test_ik_matches_in_process(client: ArmClient, name: str) -> None:
    arm = robots.load(name)
    for q in clear_configs(arm, np.random.default_rng(50), 15):
        target = arm.fk(q)
        r = client.ik(name, target.tolist())
        local = solvers.solve_ik(arm, target)
        assert r.status == "ok" and np.allclose(r.q, local.q, atol=1e-12)
        assert np.linalg.norm(arm.fk(r.q) - target) < 1e-9


def test_one_point_answers_alike_by_either_check(client: ArmClient) -> None:
    """A plain ``{"target": [x, y, z]}`` is checked in one pass (protocol.plain_point); the
    same request with an option at its default takes the full check: the answers agree, for
    targets reached, out of reach and under the floor, and out of bounds is refused alike."""
    arm = robots.load("insomniac")
    points = [arm.fk(q).tolist() for q in clear_configs(arm, np.random.default_rng(52), 5)]
    for t in [*points, [2.0, 0.0, 0.0], [0.3, 0.0, -0.05], [11.0, 0.0, 0.0]]:
        plain = raw(client, "insomniac/ik", json.dumps({"target": t}).encode())
        full = raw(client, "insomniac/ik", json.dumps({"target": t, "quantise": False}).encode())
        for _, reply in (plain, full):
            reply.pop("service")
        assert plain == full, t


def test_ik_batch_and_sensor_target(client: ArmClient) -> None:
    arm = robots.load("insomniac")
    pts = [arm.fk(q).tolist() for q in clear_configs(arm, np.random.default_rng(51), 50)] + [[2.0, 0.0, 0.0]]
    r = client.ik_batch("insomniac", [*pts, [0.3, 0.0, -0.05]])
    assert r["status"][:50] == ["ok"] * 50 and r["status"][50:] == ["unreachable", "collision"]
    assert r["contact"][49:] == [None, None, ["tool", "ground"]]
    under = client.ik("insomniac", [0.3, 0.0, -0.05])  # seed 001: nothing below the floor
    assert under.status == "collision" and under.contact == ("tool", "ground") and "below the ground" in under.reason
    s = client.ik("insomniac", {"sensor": "et_left", "range": 0.25, "bearing": -0.3}, approach="parallel")
    assert s.status == "ok"


def test_plan(client: ArmClient) -> None:
    arm = robots.load("gupta3")
    tr = client.plan("gupta3", [0.5, 1.0, -1.2], start=[0.0, 1.2, -1.0])
    assert np.allclose(tr.position[0], [0.0, 1.2, -1.0]) and np.allclose(tr.position[-1], [0.5, 1.0, -1.2])
    assert np.array_equal(tr.commands, arm.actuators.commands(tr.position))
    line = client.plan("insomniac", {"target": [0.25, 0.05, 0.25]}, path="line", start=robots.load("insomniac").neutral)
    assert line.path == "line"


BAD = [
    # (key, payload, code, field)
    ("gupta3/ik", b"{not json", "bad_request", "payload"),
    ("gupta3/ik", b"\xff\xfe", "bad_request", "payload"),
    ("gupta3/ik", b"[1, 2, 3]", "bad_request", "payload"),
    ("gupta3/ik", b'{"target": [0.1, NaN, 0.1]}', "bad_request", "payload"),
    ("gupta3/ik", b'{"target": [0.1, 0.1]}', "bad_request", "target"),
    ("gupta3/ik", b'{"target": [0.1, 0.0, 0.1], "aproach": "free"}', "bad_request", "aproach"),
    ("gupta3/ik", b"{}", "bad_request", "target"),
    ("gupta3/ik", b'{"target": [0.1, 0.0, 0.1], "approach": "parallel"}', "bad_request", "approach"),
    ("gupta3/ik", b'{"target": [0.1, 0.0, 0.1], "protocol": 2}', "bad_request", "protocol"),
    ("gupta3/ik", b'{"target": ' + b"[" * 50 + b"]" * 50 + b"}", "bad_request", "payload"),
    ("gupta3/fk", b'{"q": [0, 1]}', "bad_request", "q"),
    ("gupta3/plan", b'{"goal": [0.0, 1.0, 0.5]}', "bad_request", "goal"),
    ("gupta3/plan", b'{"goal": {"target": [3.0, 0.0, 0.0]}}', "unreachable", "goal"),
    ("gupta3/plan", b'{"goal": [0.5, 1.0, -1.0], "speed": 2}', "bad_request", "speed"),
    ("insomniac/plan", b'{"goal": {"target": [0.3, 0.0, -0.05]}}', "collision", "goal"),  # under the floor
    ("insomniac/plan", b'{"goal": {"target": [0.3, 0.0, -0.05]}, "path": "line"}', "collision", "goal"),
    ("gupta3/move", b'{"goal": [0.5, 1.0, -1.0]}', "no_adapter", None),
    ("gupta4/ik", b'{"target": [0.1, 0.0, 0.1]}', "unknown_robot", None),
    ("gupta3/dance", b"{}", "unknown_verb", None),
    ("gupta3/ik/extra", b"{}", "unknown_verb", None),
]


@pytest.mark.parametrize(("key", "payload", "code", "field"), BAD)
def test_errors(client: ArmClient, key: str, payload: bytes, code: str, field: str | None) -> None:
    kind, reply = raw(client, key, payload)
    assert kind == "err"
    assert reply["code"] == code, reply
    assert reply["message"]
    if field is not None:
        assert reply.get("field") == field, reply


def test_oversized_payload_and_batch(client: ArmClient, service: object) -> None:
    kind, reply = raw(client, "gupta3/ik", b'{"target": [0.1, 0.0, 0.1], "pad": "' + b"x" * 1_100_000 + b'"}')
    assert kind == "err" and reply["code"] == "too_large"
    kind, reply = raw(client, "gupta3/ik", json.dumps({"targets": [[0.1, 0.0, 0.1]] * 10_001}).encode())
    assert kind == "err" and reply["code"] == "too_large" and reply["field"] == "targets"
    assert client.ik("gupta3", [0.15, 0.0, 0.1]).status == "ok"  # still serving


def test_no_trajectory_published_for_refused_requests(client: ArmClient, router: str) -> None:
    got: list[bytes] = []
    sub = client.session.declare_subscriber("armd/*/trajectory", lambda s: got.append(s.payload.to_bytes()))
    try:
        for payload in (b'{"goal": [0.0, 1.0, 0.5]}', b"nope", b'{"goal": {"target": [3, 0, 0]}}'):
            raw(client, "gupta3/move", payload)
        raw(client, "insomniac/move", b'{"goal": {"target": [0.3, 0.0, -0.05]}}')  # (collision)
        time.sleep(0.3)
    finally:
        sub.undeclare()
    assert got == []


def test_internal_errors_are_answered_and_the_service_lives_on(
    client: ArmClient, service: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(arm: object, req: object, deadline: object) -> dict[str, object]:
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(service.handlers, "fk", broken)  # type: ignore[attr-defined]
    kind, reply = raw(client, "gupta3/fk", b'{"q": [0, 1, -1]}')
    assert kind == "err" and reply["code"] == "internal" and "ZeroDivisionError" in str(reply["message"])
    monkeypatch.undo()
    assert client.fk("gupta3", [0, 1, -1]).within_limits


def test_counters_and_the_debug_line(client: ArmClient, service: object, caplog: pytest.LogCaptureFixture) -> None:
    """Quick requests (answered on the receiving thread) are counted served, errors as errors,
    never in flight; with the level at debug, each request is logged with its outcome and time."""
    import logging

    from tests.conftest import wait_for

    # (a request is counted just after its reply leaves: the last test's may land a moment late)
    seen: list[dict[str, int]] = []

    def settled() -> bool:  # the same counts twice, 20 ms apart
        seen.append(service.stats())  # type: ignore[attr-defined]
        return len(seen) > 1 and seen[-1] == seen[-2]

    wait_for(settled, what="the counters settled")
    before = service.stats()  # type: ignore[attr-defined]
    with caplog.at_level(logging.DEBUG, logger="armd.service"):
        assert client.fk("gupta3", [0, 1, -1]).within_limits
        assert raw(client, "gupta3/ik", b'{"target": [0.1, 0.0, 0.1], "aproach": 1}')[0] == "err"
        assert raw(client, "*/fk", b'{"q": [0, 1, -1]}')[1]["code"] == "unknown_robot"  # a glob is no robot
        wait_for(lambda: sum(r.getMessage().startswith("armd/") for r in caplog.records) >= 3, what="three debug lines")
    after = service.stats()  # type: ignore[attr-defined]
    assert after["served"] - before["served"] == 3 and after["errors"] - before["errors"] == 2
    assert after["in_flight"] == 0
    lines = [r.getMessage() for r in caplog.records if r.name == "armd.service.server"]
    assert any(m.startswith("armd/gupta3/fk ok in ") and m.endswith(" ms") for m in lines), lines
    assert any(m.startswith("armd/gupta3/ik error in ") for m in lines), lines


def test_arm_client_keeps_a_querier_per_key(router: str, service: object, monkeypatch: pytest.MonkeyPatch) -> None:
    import armd.clients.client as module

    with ArmClient(router, timeout=10.0, deadline=5.0) as c:
        req = {"q": [0, 1, -1]}
        for _ in range(3):
            assert c.call("gupta3/fk", req)["within_limits"]
        assert req == {"q": [0, 1, -1]}  # the client's deadline went into the payload, not into the caller's dict
        assert list(c._queriers) == [("gupta3/fk", 10.0)]
        assert c.call("gupta3/fk", req, timeout=7.0)["within_limits"]  # a timeout of its own: a querier of its own
        assert set(c._queriers) == {("gupta3/fk", 10.0), ("gupta3/fk", 7.0)}
        monkeypatch.setattr(module, "MAX_QUERIERS", 2)
        for _ in range(2):  # past the bound: still answered, nothing more kept
            assert c.ik("insomniac", [0.25, 0.05, 0.12]).status in ("ok", "approximate", "unreachable")
        assert len(c._queriers) == 2
        with pytest.raises(ServiceError) as e:  # errors come back the same way through a kept querier
            c.call("gupta3/fk", {"q": [0, 1]})
        assert e.value.code == "bad_request" and e.value.field == "q"


def test_one_arm_client_shared_by_threads(router: str, service: object) -> None:
    """Threads asking through one client share its querier: each gets its own reply."""
    arm = robots.load("sg5ut")
    targets = [arm.fk(q) for q in random_in_limits(arm, 48, seed=53)]
    expected = [solvers.solve_ik(arm, t).q for t in targets]
    failures: list[str] = []
    with ArmClient(router, timeout=10.0) as c:

        def worker(k: int) -> None:
            for i in range(k, len(targets), 8):
                try:
                    if not np.allclose(c.ik("sg5ut", targets[i]).q, expected[i], atol=1e-12):
                        failures.append(f"wrong answer {i}")
                except Exception as e:
                    failures.append(repr(e))

        _in_threads(worker, 8)
        assert list(c._queriers) == [("sg5ut/ik", 10.0)]
    assert failures == []


def test_concurrent_clients(router: str, service: object) -> None:
    arm = robots.load("sg5ut")
    targets = [arm.fk(q) for q in random_in_limits(arm, 40, seed=52)]
    expected = [solvers.solve_ik(arm, t).q for t in targets]
    failures: list[str] = []

    def worker(k: int) -> None:
        with ArmClient(router, timeout=10.0) as c:
            for i in range(k % 5, len(targets), 5):
                try:
                    r = c.ik("sg5ut", targets[i].tolist())
                    if not np.allclose(r.q, expected[i], atol=1e-12):
                        failures.append(f"wrong answer {i}")
                except Exception as e:
                    failures.append(repr(e))

    _in_threads(worker, 8)
    assert failures == []


def _in_threads(worker: Callable[[int], None], n: int) -> None:
    """``worker(k)`` for k in 0..n-1, each on its own thread, all at once; waits for them."""
    threads = [threading.Thread(target=worker, args=(k,)) for k in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)


@pytest.fixture(scope="module")
def sim(router: str, service: object) -> Iterator[SimAdapter]:
    from armd.service.zconfig import network_config

    session = zenoh.open(network_config(connect=[router]))
    adapter = SimAdapter(session, robots.load("gupta3"), time_scale=5.0)
    deadline = time.monotonic() + 5
    while service._adapter_count(robots.load("gupta3")) == 0 and time.monotonic() < deadline:  # type: ignore[attr-defined]
        time.sleep(0.05)
    yield adapter
    adapter.close()
    session.close()


def test_move_with_a_simulated_arm(client: ArmClient, sim: SimAdapter) -> None:
    events: list[dict[str, object]] = []
    sub = client.session.declare_subscriber(
        "armd/gupta3/events", lambda s: events.append(json.loads(s.payload.to_bytes()))
    )
    published, trajectories = collect(client, "armd/gupta3/trajectory")
    time.sleep(0.5)  # subscriptions reach the publishers through the router a moment later (no ack to wait for)
    try:
        goal = np.array([0.6, 1.1, -1.3])
        r = client.move("gupta3", goal.tolist(), wait=True, wait_timeout=10)
        assert np.allclose(sim.position, goal, atol=1e-9)
        state = client.state("gupta3")
        assert state["source"] == "adapter" and not state["moving"]
        # the next move starts from where the adapter says the arm is
        r2 = client.move("gupta3", {"target": [0.18, 0.05, 0.1]}, wait=True, wait_timeout=10)
        assert r2.start_source == "adapter"
        assert np.linalg.norm(robots.load("gupta3").fk(sim.position) - [0.18, 0.05, 0.1]) < 1e-6
        time.sleep(0.2)
    finally:
        sub.undeclare()
        trajectories.undeclare()  # type: ignore[attr-defined]
    by_id = {m["id"]: m for m in published}
    assert "target" not in by_id[r.id]  # a joint goal
    assert by_id[r2.id]["target"] == [0.18, 0.05, 0.1]  # a Cartesian goal: its target travels with it
    kinds = [e["event"] for e in events if e.get("id") == r.id]
    assert kinds[:2] == ["accepted", "started"] and "done" in kinds


def test_gripper(client: ArmClient, sim: SimAdapter) -> None:
    with pytest.raises(ServiceError) as e:
        client.gripper("gupta3", 0.5)
    assert e.value.code == "bad_request"  # the gupta3 has no gripper
    with pytest.raises(ServiceError) as e:
        client.gripper("insomniac", 0.5)
    assert e.value.code == "no_adapter"
    for bad in (1.5, -0.1):
        with pytest.raises(ServiceError) as e:
            client.gripper("insomniac", bad)
        assert e.value.code in ("bad_request", "no_adapter")


def test_stop_mid_move(client: ArmClient, sim: SimAdapter) -> None:
    client.move("gupta3", [-0.8, 1.5, -0.6], speed=0.3)
    time.sleep(0.3)
    assert client.state("gupta3")["moving"]
    stopped = client.stop("gupta3")
    assert stopped["adapters"] == 1
    s = client.wait_until_still("gupta3", timeout=5.0)
    assert not np.allclose(s["position"], [-0.8, 1.5, -0.6], atol=1e-3)  # halted short of the goal
    arm = robots.load("gupta3")
    assert arm.limits.contains(np.array(s["position"]), tol=1e-9)


def test_a_gripper_sensor_reading_is_converted_where_the_adapter_says_the_arm_is(
    client: ArmClient, router: str, service: object
) -> None:
    """No adapter: the reading of the GP2D120 on the gripper is refused (position_unknown), never
    converted at the neutral pose. With the simulated arm at a pose: converted there (ik and plan;
    move takes the same path, service/handlers.py _present); a seed given: converted at the seed."""
    from armd.service.zconfig import network_config

    arm = robots.load("insomniac")
    reading = {"sensor": "gripper_et", "range": 0.08}
    for key, payload in [
        ("insomniac/ik", {"target": reading}),
        ("insomniac/plan", {"goal": {"target": reading}}),
    ]:
        with pytest.raises(ArmdError) as e:
            client.call(key, payload)
        assert e.value.code == "position_unknown" and "gripper_et" in e.value.message, e.value
    session = zenoh.open(network_config(connect=[router]))
    adapter = SimAdapter(session, arm, time_scale=5.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")  # type: ignore[attr-defined]
        q = np.array([0.5, 1.4, -1.3, -0.4, 0.2])
        client.move("insomniac", q.tolist(), wait=True, wait_timeout=20)
        here = adapter.position.copy()
        seen = arm.sensor_point("gripper_et", 0.08, q=here)
        r = client.ik("insomniac", reading)
        assert np.allclose(r.raw["target"], seen, atol=1e-9)
        plan = client.plan("insomniac", {"target": reading})
        assert np.linalg.norm(arm.fk(plan.position[-1]) - seen) < 1e-3
        at = np.array(arm.neutral)
        r = client.ik("insomniac", reading, seed=at.tolist())
        assert np.allclose(r.raw["target"], arm.sensor_point("gripper_et", 0.08, q=at), atol=1e-9)
    finally:
        adapter.close()
        session.close()


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "desk4"])
def test_every_arm_moves_through_the_simulator(client: ArmClient, router: str, service: object, name: str) -> None:
    from armd.service.zconfig import network_config

    arm = robots.load(name)
    session = zenoh.open(network_config(connect=[router]))
    adapter = SimAdapter(session, arm, time_scale=5.0, lag=0.02)
    try:
        deadline = time.monotonic() + 5
        while service._adapter_count(arm) == 0:  # type: ignore[attr-defined]
            assert time.monotonic() < deadline
            time.sleep(0.05)
        q = clear_configs(arm, np.random.default_rng(60), 1)[0]
        target = arm.fk(q)
        client.move(name, {"target": target.tolist()}, wait=True, wait_timeout=20)
        assert np.linalg.norm(arm.fk(adapter.position) - target) < 1e-3  # within 1 mm, through the servo lag
    finally:
        adapter.close()
        session.close()


def test_a_stop_is_never_refused_from_a_state_a_hair_outside_the_limits() -> None:
    """A measured state just past a position limit, moving a hair over a velocity limit (a
    stepper's whole steps, a servo's rounding): the stop goes out on estop and is answered, with
    a rest pose inside the limits; ``limit`` is not an answer to a stop. A move refuses to plan
    from there, as it should."""
    from armd.planning import JointState
    from armd.service.deadline import Deadline
    from armd.service.handlers import Handlers
    from armd.service.protocol import Limits
    from armd.service.state import StateBook

    arm = robots.load("gupta3")
    book = StateBook()
    estops: list[dict[str, object]] = []
    handlers = Handlers(
        {"gupta3": arm}, book, Limits(), lambda a, m: None, lambda a: 1, publish_estop=lambda a, m: estops.append(m)
    )
    lim = arm.limits
    q = (lim.lower + lim.upper) / 2
    q[1] = lim.upper[1] + 1.1e-3  # the shoulder decelerating onto its limit, read past it (a whole step)
    v = np.zeros(arm.nq)
    v[1] = 0.05
    v[0] = lim.velocity[0] * 1.000001  # the yaw a hair over its velocity limit
    book.report("gupta3", JointState(q, v, np.zeros(arm.nq)), True)
    r = handlers.stop(arm, {}, Deadline(time.monotonic(), 5.0))
    assert len(estops) == 1 and estops[0]["id"] == r["id"]
    assert lim.contains(np.array(r["rest"]), tol=1e-9)
    with pytest.raises(ArmdError) as e:
        handlers.move(arm, {"goal": arm.neutral.tolist()}, Deadline(time.monotonic(), 5.0))
    assert e.value.code == "bad_request"


def test_move_is_refused_while_the_adapter_does_not_know_where_the_arm_is() -> None:
    from armd.planning import JointState
    from armd.service.deadline import Deadline
    from armd.service.handlers import Handlers
    from armd.service.protocol import Limits
    from armd.service.state import StateBook

    arm = robots.load("gupta3")
    book = StateBook()
    published: list[object] = []
    handlers = Handlers({"gupta3": arm}, book, Limits(), lambda a, m: published.append(m), lambda a: 1)
    book.report("gupta3", JointState.at_rest(arm.neutral.copy()), False, homed=False)
    with pytest.raises(ArmdError) as e:
        handlers.move(arm, {"goal": [0.1, 1.0, -1.0]}, Deadline(time.monotonic(), 5.0))
    assert e.value.code == "position_unknown" and published == []
    book.report("gupta3", JointState.at_rest(arm.neutral.copy()), False, homed=True)
    handlers.move(arm, {"goal": [0.1, 1.0, -1.0]}, Deadline(time.monotonic(), 5.0))
    assert len(published) == 1
