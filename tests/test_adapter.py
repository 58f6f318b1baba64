"""What every adapter does on the Zenoh side (adapters/base.py), on the simulated arm: the
checks a trajectory passes by its motion, ids run once, the estop that needs no service."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh

from armd import planning, robots
from armd.adapters.sim import SimAdapter
from armd.adapters.trajectory_message import MAX_BYTES
from armd.clients import ArmClient
from armd.service.zconfig import network_config
from tests.conftest import wait_for

ARM = "insomniac"


@pytest.fixture
def sim(router: str) -> Iterator[tuple[SimAdapter, zenoh.Session, list[dict[str, Any]]]]:
    """A simulated insomniac on the router (no service), and the events it says."""
    session = zenoh.open(network_config(connect=[router]))
    arm = robots.load(ARM)
    adapter = SimAdapter(session, arm, prefix="t")
    events: list[dict[str, Any]] = []
    sub = session.declare_subscriber(f"t/{ARM}/events", lambda s: events.append(json.loads(s.payload.to_bytes())))
    yield adapter, session, events
    sub.undeclare()
    adapter.close()
    session.close()


def message(traj: planning.Trajectory, ident: str = "a", **changes: Any) -> dict[str, Any]:
    msg = traj.to_dict()
    msg.update({"id": ident, "kind": "move", **changes})
    return msg


def put(session: zenoh.Session, msg: dict[str, Any] | bytes) -> None:
    body = msg if isinstance(msg, bytes) else orjson.dumps(msg, option=orjson.OPT_SERIALIZE_NUMPY)
    session.put(f"t/{ARM}/trajectory", body)


def rejection(events: list[dict[str, Any]], n: int = 1) -> list[str]:
    wait_for(lambda: sum(e["event"] == "rejected" for e in events) >= n, timeout=5, what="a rejection")
    return [str(e["reason"]) for e in events if e["event"] == "rejected"]


def test_a_trajectory_is_checked_by_its_motion_not_by_what_it_declares(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    traj = planning.plan(arm, arm.neutral, [1.2, 2.0, -1.8, 1.0, 1.0])
    swing = message(traj, "swing")
    swing["position"] = traj.position[::10].tolist()
    k = len(swing["position"])
    swing.update(times=traj.times[:k].tolist(), velocity=[[0.0] * arm.nq] * k, acceleration=[[0.0] * arm.nq] * k)
    put(session, swing)  # the same path ten times as fast, declaring it stands still
    assert "finite difference" in rejection(events)[-1]
    assert np.allclose(adapter.position, arm.neutral)  # nothing moved


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"rate_hz": 1e-6}, "rate_hz must be a number in [1, 1000]"),
        ({"rate_hz": 5000}, "rate_hz must be a number in [1, 1000]"),
        ({"id": ""}, "needs an 'id'"),
        ({"kind": "dance"}, "kind must be one of"),
    ],
    ids=["slow rate", "fast rate", "no id", "bad kind"],
)
def test_malformed_trajectories_are_refused(sim: Any, change: dict[str, Any], says: str) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    put(session, message(planning.plan(arm, arm.neutral, [0.3, 1.2, -1.0, -0.5, 0.0]), **change))
    assert says in rejection(events)[-1]
    assert np.allclose(adapter.position, arm.neutral)


def test_times_must_start_at_zero_and_the_size_is_bounded_before_parsing(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    traj = planning.plan(arm, arm.neutral, [0.3, 1.2, -1.0, -0.5, 0.0])
    put(session, message(traj, times=(traj.times + 1000.0).tolist()))
    assert "start at 0" in rejection(events)[-1]
    put(session, b'{"times": [' + b"0," * (MAX_BYTES // 2) + b"0]}")
    assert "at most" in rejection(events, 2)[-1] and "bytes" in rejection(events, 2)[-1]
    assert np.allclose(adapter.position, arm.neutral)


def test_a_trajectory_must_start_where_the_arm_is(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    elsewhere = np.array([0.5, 1.5, -1.2, -0.4, 0.3])
    put(session, message(planning.plan(arm, elsewhere, [0.3, 1.2, -1.0, -0.5, 0.0])))
    reason = rejection(events)[-1]
    assert "starts" in reason and "planned from another state" in reason
    put(
        session,
        message(
            planning.plan(arm, arm.neutral, arm.neutral),
            ident="one-sample",
            position=[elsewhere.tolist()],
            times=[0.0],
            velocity=[[0] * 5],
            acceleration=[[0] * 5],
        ),
    )
    assert "starts" in rejection(events, 2)[-1]  # (a single far sample: the jump the issue saw at 1561 rad/s)
    assert np.allclose(adapter.position, arm.neutral)


def test_an_id_runs_at_most_once(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    goal = np.array([0.3, 1.2, -1.0, -0.5, 0.0])
    msg = message(planning.plan(arm, arm.neutral, goal), "once")
    put(session, msg)
    wait_for(lambda: any(e["event"] == "done" and e.get("id") == "once" for e in events), timeout=10, what="done")
    back = message(planning.plan(arm, goal, arm.neutral), "back")
    put(session, back)
    wait_for(lambda: any(e["event"] == "done" and e.get("id") == "back" for e in events), timeout=10, what="back")
    put(session, msg)  # replayed: refused, although it starts where the arm is again
    assert "at most once" in rejection(events)[-1]
    time.sleep(0.3)
    assert np.allclose(adapter.position, arm.neutral)


def test_estop_needs_no_service_and_brakes_from_the_adapters_own_state(router: str, sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    goal = [1.2, 2.0, -1.8, 1.0, 1.0]
    traj = planning.plan(arm, arm.neutral, goal)
    put(session, message(traj, "far"))
    wait_for(lambda: any(e["event"] == "started" for e in events), timeout=5, what="the move")
    time.sleep(0.3 * traj.duration)
    with ArmClient(router, prefix="t") as c:  # no service on prefix t: the estop goes to the adapter
        acks = c.estop(ARM, wait=0.5)
    assert len(acks) == 1 and acks[0]["adapter"] == adapter.id
    wait_for(
        lambda: any(e["event"] == "done" and e.get("id") == acks[0]["id"] for e in events),
        timeout=5,
        what="the stop done",
    )
    assert any(e["event"] == "aborted" and e.get("id") == "far" for e in events)
    here = adapter.position.copy()
    assert np.max(np.abs(here - goal)) > 0.1  # stopped short of the goal
    assert arm.limits.contains(here)
    assert acks[0]["duration"] <= planning.plan_stop(arm, traj.at(0.3 * traj.duration)).duration + 0.2


def test_an_estop_that_is_not_json_still_stops(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    put(session, message(planning.plan(arm, arm.neutral, [1.2, 2.0, -1.8, 1.0, 1.0]), "far"))
    wait_for(lambda: any(e["event"] == "started" for e in events), timeout=5, what="the move")
    session.put(f"t/{ARM}/estop", b"\xff not json")
    wait_for(
        lambda: any(e["event"] == "aborted" and e.get("id") == "far" for e in events),
        timeout=5,
        what="the move aborted",
    )


def test_a_stop_trajectory_from_anyone_is_the_adapters_own_stop(sim: Any) -> None:
    """A published ``kind: "stop"`` does not drive the arm through its samples (a forger's
    'stop' that swings the arm): the adapter brakes from its own state instead."""
    adapter, session, events = sim
    arm = adapter.robot
    swing = planning.plan(arm, arm.neutral, [0.6, 1.2, -1.0, -0.5, 0.0])
    put(session, message(swing, "stop-swing", kind="stop"))
    wait_for(
        lambda: any(e["event"] == "done" and e.get("id") == "stop-swing" for e in events), timeout=5, what="the stop"
    )
    assert np.allclose(adapter.position, arm.neutral)  # at rest, it stays


def test_the_simulator_has_nothing_to_unlock(sim: Any) -> None:
    _, session, events = sim
    session.put(f"t/{ARM}/unlock", b'{"how": "assume_rest"}')
    assert "nothing to unlock" in rejection(events)[-1]
    session.put(f"t/{ARM}/unlock", b'{"how": "jiggle"}')
    assert "one of home, assume_rest" in rejection(events, 2)[-1]


def test_an_adapter_finishes_what_it_accepted_when_the_service_dies(router: str, sim: Any) -> None:
    """The service goes away mid-move: the adapter needs nothing of it to finish the move."""
    from armd.service.server import Service

    adapter, _, events = sim
    arm = adapter.robot
    service_session = zenoh.open(network_config(connect=[router]))
    service = Service(service_session, {ARM: arm}, prefix="t")
    goal = [0.6, 1.4, -1.2, -0.4, 0.3]
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")
        with ArmClient(router, prefix="t") as c:
            r = c.move(ARM, goal)
    finally:
        service.close()
        service_session.close()  # mid-move: the service is gone
    wait_for(
        lambda: any(e["event"] == "done" and e.get("id") == r.id for e in events),
        timeout=r.duration + 5,
        what="the move done",
    )
    assert np.allclose(adapter.position, goal, atol=1e-9)
