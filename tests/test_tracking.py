"""The tracking stream (armd/<robot>/track, issue 35): one cycle's plan (planning/online.py),
the adapter's splices (adapters/base.py), and the stream end to end through a real router, the
service and a simulated arm, driven by the Python client, as a user drives it."""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh

from armd import planning, robots
from armd.adapters.sim import SimAdapter
from armd.adapters.trajectory_message import Command
from armd.clients import ArmClient
from armd.errors import BadRequest, NoReply
from armd.planning import JointState
from armd.planning.online import track_step
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import wait_for

ARM = "insomniac"
RATE = 200.0


# -- one cycle ---------------------------------------------------------------------------------


def within_limits(arm: robots.Robot, position: np.ndarray, dt: float, slack: float = 1e-6) -> dict[str, float]:
    """The samples' finite-difference velocity, acceleration and jerk over the limits (ratios)."""
    v = np.diff(position, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    lim = arm.limits
    out = {
        "v": float(np.max(np.abs(v) / lim.velocity, initial=0.0)),
        "a": float(np.max(np.abs(a) / lim.acceleration, initial=0.0)),
        "j": float(np.max(np.abs(j) / lim.jerk, initial=0.0)),
    }
    assert all(r <= 1 + slack for r in out.values()), out
    for q in position:
        assert lim.contains(q, tol=1e-9), q
    return out


def test_a_cycle_reaches_its_goal_at_rest_when_the_horizon_allows() -> None:
    arm = robots.load(ARM)
    goal = np.array(arm.neutral) + 0.2
    step = track_step(arm, JointState.at_rest(np.array(arm.neutral)), goal, horizon=5.0, speed=1.0, rate_hz=RATE)
    traj = step.trajectory
    assert not step.braked and step.hit is None
    assert np.allclose(traj.position[-1], goal, atol=1e-9)
    assert np.allclose(traj.velocity[-1], 0.0, atol=1e-9)
    within_limits(arm, traj.position, 1 / RATE)


def test_a_cycle_brakes_to_rest_where_its_horizon_ends() -> None:
    arm = robots.load(ARM)
    goal = np.array(arm.neutral) + 0.5
    step = track_step(arm, JointState.at_rest(np.array(arm.neutral)), goal, horizon=0.1, speed=1.0, rate_hz=RATE)
    traj = step.trajectory
    assert step.braked
    assert np.allclose(traj.velocity[-1], 0.0, atol=1e-9)  # at rest, short of the goal
    assert np.max(np.abs(traj.position[-1] - goal)) > 0.1
    # up to the horizon it is the way to the goal: moving there when the brake begins
    assert np.any(np.abs(traj.velocity[int(0.1 * RATE)]) > 0.1)
    within_limits(arm, traj.position, 1 / RATE)


def test_a_cycle_from_a_sample_of_the_last_joins_it_within_every_limit() -> None:
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    first = track_step(arm, JointState.at_rest(q0), q0 + 0.4, horizon=0.25, speed=1.0, rate_hz=RATE).trajectory
    k = 30  # the next cycle takes over at its 30th sample, toward another goal
    at = JointState(first.position[k], first.velocity[k], first.acceleration[k])
    second = track_step(arm, at, q0 - 0.2, horizon=0.25, speed=1.0, rate_hz=RATE).trajectory
    joined = np.vstack([first.position[:k], second.position])
    within_limits(arm, joined, 1 / RATE)


def test_a_moving_reference_is_followed_with_no_lag() -> None:
    """On the reference, the arm moves with it: no braking lag (the stream's own pace)."""
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    v = np.array([0.3, -0.2, 0.2, 0.1, 0.0])
    ref = JointState(q0, v, np.zeros(arm.nq))
    step = track_step(arm, ref, q0, horizon=0.25, speed=1.0, rate_hz=RATE, reference=ref, cruise=0.05)
    traj = step.trajectory
    n = int(0.05 * RATE)
    expect = q0 + v * traj.times[:n, None]
    assert np.max(np.abs(traj.position[:n] - expect)) < 1e-9  # on the reference for the cruise
    assert np.allclose(traj.velocity[-1], 0.0, atol=1e-9)  # then braked to rest
    within_limits(arm, traj.position, 1 / RATE)


def test_off_the_reference_the_error_is_taken_out_within_the_limits() -> None:
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    v = np.array([0.3, -0.2, 0.2, 0.1, 0.0])
    start = JointState(q0 + 0.01, np.zeros(arm.nq), np.zeros(arm.nq))  # behind, and not moving yet
    step = track_step(
        arm, start, q0, horizon=0.25, speed=1.0, rate_hz=RATE, reference=JointState(q0, v, np.zeros(arm.nq)), cruise=0.1
    )
    traj = step.trajectory
    assert np.allclose(traj.position[0], start.position)
    within_limits(arm, traj.position, 1 / RATE)


def test_a_cycle_whose_way_touches_the_world_stops_short_of_it() -> None:
    arm = robots.load(ARM)
    world = arm.collision
    assert world is not None and world.ground is not None
    q0 = np.array(arm.neutral)
    down = q0.copy()
    down[1] -= 1.0  # the shoulder forward and down: the gripper through the floor
    step = track_step(arm, JointState.at_rest(q0), down, horizon=5.0, speed=1.0, rate_hz=RATE)
    assert step.braked and step.hit is not None
    for q in step.trajectory.position:
        assert world.first_contact(q) is None
    within_limits(arm, step.trajectory.position, 1 / RATE)


# -- the adapter's splices ---------------------------------------------------------------------


@pytest.fixture
def sim(router: str) -> Iterator[tuple[SimAdapter, zenoh.Session, list[dict[str, Any]]]]:
    session = zenoh.open(network_config(connect=[router]))
    adapter = SimAdapter(session, robots.load(ARM), prefix="s")
    events: list[dict[str, Any]] = []
    sub = session.declare_subscriber(f"s/{ARM}/events", lambda s: events.append(json.loads(s.payload.to_bytes())))
    yield adapter, session, events
    sub.undeclare()
    adapter.close()
    session.close()


def stream_message(traj: planning.Trajectory, ident: str, track: str = "t1", **more: Any) -> bytes:
    msg = traj.to_dict()
    msg.update({"id": ident, "kind": "move", "track": track, **more})
    return orjson.dumps(msg)


def started(arm: robots.Robot, session: zenoh.Session, events: list[dict[str, Any]], q0: np.ndarray) -> Any:
    """A stream's first trajectory (0.6 rad on every joint, braked at 0.5 s), put and started."""
    first = track_step(arm, JointState.at_rest(q0), q0 + 0.6, horizon=0.5, speed=1.0, rate_hz=RATE).trajectory
    session.put(f"s/{ARM}/trajectory", stream_message(first, "one"))
    wait_for(lambda: any(e["event"] == "started" and e.get("id") == "one" for e in events), 5, "the first to start")
    return first


def test_a_splice_takes_over_at_its_sample_and_a_wrong_one_is_refused(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    q0 = np.array(arm.neutral)
    first = started(arm, session, events, q0)
    k = 60  # 0.3 s in: ahead of the adapter
    at = JointState(first.position[k], first.velocity[k], first.acceleration[k])
    second = track_step(arm, at, q0 - 0.3, horizon=0.5, speed=1.0, rate_hz=RATE).trajectory
    wrong = stream_message(second, "stray", splice={"after": "nobody", "at": k / RATE})
    session.put(f"s/{ARM}/trajectory", wrong)
    session.put(f"s/{ARM}/trajectory", stream_message(second, "two", splice={"after": "one", "at": k / RATE}))
    wait_for(lambda: any(e["event"] == "done" for e in events), 10, "the stream to end")
    refused = [e for e in events if e["event"] == "rejected"]
    assert [e["id"] for e in refused] == ["stray"] and "takes over from nobody" in refused[0]["reason"]
    assert not any(e["event"] == "aborted" for e in events)  # a splice replaces nothing: it goes on
    assert np.allclose(adapter.position, second.position[-1], atol=1e-9)  # the second one's end


def test_a_splice_that_would_jump_or_comes_late_is_refused(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    q0 = np.array(arm.neutral)
    first = started(arm, session, events, q0)
    k = 80
    at = JointState(first.position[k], first.velocity[k], first.acceleration[k])
    second = track_step(arm, at, q0, horizon=0.5, speed=1.0, rate_hz=RATE).trajectory
    off = second.to_dict()
    off["position"] = (np.array(off["position"]) + 0.002).tolist()  # 2 mrad off where it takes over
    session.put(
        f"s/{ARM}/trajectory",
        orjson.dumps({**off, "id": "off", "kind": "move", "track": "t1", "splice": {"after": "one", "at": k / RATE}}),
    )
    late = 2  # 10 ms in: already past
    at = JointState(first.position[late], first.velocity[late], first.acceleration[late])
    third = track_step(arm, at, q0, horizon=0.5, speed=1.0, rate_hz=RATE).trajectory
    time.sleep(0.1)
    session.put(f"s/{ARM}/trajectory", stream_message(third, "late", splice={"after": "one", "at": late / RATE}))
    wait_for(lambda: sum(e["event"] == "rejected" for e in events) >= 2, 5, "two refusals")
    reasons = {e["id"]: e["reason"] for e in events if e["event"] == "rejected"}
    assert "starts 0.002 rad from one's sample" in reasons["off"]
    assert "after its time" in reasons["late"]
    wait_for(lambda: any(e["event"] == "done" and e.get("id") == "one" for e in events), 10, "the first to end")
    assert np.allclose(adapter.position, first.position[-1], atol=1e-9)  # the first, to its own end


def test_malformed_splices_are_refused_before_anything_moves(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    traj = track_step(
        arm, JointState.at_rest(np.array(arm.neutral)), np.array(arm.neutral) + 0.1, horizon=1, speed=1.0, rate_hz=RATE
    ).trajectory
    for ident, splice in (
        ("a", {"after": "x", "at": 0.0012}),
        ("b", {"after": "", "at": 0.0}),
        ("c", [1, 2]),
        ("d", {"after": "x", "at": -1}),
        ("e", {"after": "x"}),
    ):
        session.put(f"s/{ARM}/trajectory", stream_message(traj, ident, splice=splice))
    wait_for(lambda: sum(e["event"] == "rejected" for e in events) >= 5, 5, "five refusals")
    assert not any(e["event"] == "started" for e in events)
    assert np.allclose(adapter.position, arm.neutral)


def test_after_an_estop_nothing_of_its_stream_runs(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    q0 = np.array(arm.neutral)
    started(arm, session, events, q0)
    session.put(f"s/{ARM}/estop", b"{}")
    wait_for(lambda: any(e["event"] == "done" and e.get("id") != "one" for e in events), 5, "the stop to end")
    rest = adapter.position.copy()
    again = track_step(arm, JointState.at_rest(rest), q0, horizon=0.5, speed=1.0, rate_hz=RATE).trajectory
    session.put(f"s/{ARM}/trajectory", stream_message(again, "again"))  # the same stream, from rest: refused
    wait_for(lambda: any(e["event"] == "rejected" for e in events), 5, "a refusal")
    assert "was stopped here" in next(e["reason"] for e in events if e["event"] == "rejected")
    time.sleep(0.1)
    assert np.allclose(adapter.position, rest)


def test_a_stream_starts_from_rest_only(sim: Any) -> None:
    adapter, session, events = sim
    arm = adapter.robot
    q0 = np.array(arm.neutral)
    move = planning.plan(arm, q0, q0 + 0.6)
    msg = move.to_dict()
    session.put(f"s/{ARM}/trajectory", orjson.dumps({**msg, "id": "m", "kind": "move"}))
    wait_for(lambda: any(e["event"] == "started" for e in events), 5, "the move to start")
    stream = track_step(
        arm, JointState.at_rest(adapter.position.copy()), q0, horizon=0.5, speed=1.0, rate_hz=RATE
    ).trajectory
    session.put(f"s/{ARM}/trajectory", stream_message(stream, "s"))
    wait_for(lambda: any(e["event"] == "rejected" for e in events), 5, "a refusal")
    assert "starts from rest" in next(e["reason"] for e in events if e["event"] == "rejected")


# -- the stream, end to end ------------------------------------------------------------------------


class Recorder:
    """A simulated arm that keeps what it ran: each trajectory once, in order (what the
    controller got is those, each up to where the next took over)."""

    def __init__(self, session: zenoh.Session, arm: robots.Robot, prefix: str) -> None:
        self.ran: list[Command] = []
        self.times: list[tuple[float, np.ndarray]] = []
        self.lock = threading.Lock()
        recorder = self

        class Recording(SimAdapter):
            def execute(self, cmd: Command, t: float, first: bool) -> bool:
                done = super().execute(cmd, t, first)
                with recorder.lock:
                    if not recorder.ran or recorder.ran[-1] is not cmd:
                        recorder.ran.append(cmd)
                    recorder.times.append((time.monotonic(), self.position.copy()))
                return done

            def spliced(self, before: Command, cmd: Command) -> None:
                super().spliced(before, cmd)
                with recorder.lock:  # (two may take over in one pass of a late loop: each is kept)
                    if not recorder.ran or recorder.ran[-1] is not before:
                        recorder.ran.append(before)
                    recorder.ran.append(cmd)

        self.adapter = Recording(session, arm, prefix=prefix)

    def commanded(self) -> np.ndarray:
        """The positions the arm was sent, sample by sample (200 Hz), splices joined."""
        with self.lock:
            ran = list(self.ran)
        parts = []
        for i, cmd in enumerate(ran):
            nxt = ran[i + 1] if i + 1 < len(ran) else None
            if nxt is not None and nxt.after == cmd.id:
                parts.append(cmd.position[: round(nxt.at * cmd.rate_hz)])
            else:
                parts.append(cmd.position)
        return np.vstack(parts)


@pytest.fixture(scope="module")
def served(router: str) -> Iterator[tuple[str, Service]]:
    session = zenoh.open(network_config(connect=[router]))
    service = Service(session, {ARM: robots.load(ARM)}, prefix="tr")
    yield router, service
    service.close()
    session.close()


@pytest.fixture
def arm_sim(served: tuple[str, Service]) -> Iterator[Recorder]:
    router, service = served
    session = zenoh.open(network_config(connect=[router]))
    time.sleep(0.3)  # (the last test's session's deadman: run out, so that this test's session begins at once)
    rec = Recorder(session, robots.load(ARM), "tr")
    wait_for(lambda: service.book.current(service.arms[ARM]).source == "adapter", 10, "the adapter's state")
    yield rec
    rec.adapter.close()
    session.close()
    wait_for(lambda: service._adapter_count(service.arms[ARM]) == 0, 10, "the adapter gone")


@pytest.fixture
def armd(served: tuple[str, Service]) -> Iterator[ArmClient]:
    with ArmClient(served[0], prefix="tr", timeout=10.0) as client:
        yield client


def stream_circle(
    track: Any, centre: np.ndarray, radius: float, speed: float, seconds: float
) -> list[tuple[float, np.ndarray]]:
    """Targets on a circle in the y-z plane at ``speed`` m/s, put at 100 Hz on the test's clock."""
    sent = []
    w = speed / radius
    t0 = time.monotonic()
    for k in range(int(seconds * 100)):
        a = w * k / 100
        p = centre + radius * np.array([0.0, math.cos(a), math.sin(a)])
        sent.append((time.monotonic(), p))
        track.send(target=p.tolist())
        time.sleep(max(0.0, t0 + (k + 1) / 100 - time.monotonic()))
    return sent


def resting(rec: Recorder, settle: float = 0.2) -> np.ndarray:
    """Where the arm came to rest (its position unchanged for ``settle`` s)."""

    def still() -> bool:
        with rec.lock:
            times = list(rec.times)
        return bool(times) and time.monotonic() - times[-1][0] > settle

    wait_for(still, 10, "the arm to rest")
    return rec.adapter.position.copy()


def test_a_circle_streamed_at_100_hz_is_followed_within_every_limit(armd: ArmClient, arm_sim: Recorder) -> None:
    arm = robots.load(ARM)
    centre = arm.fk(arm.neutral) + np.array([0.0, -0.05, -0.05])
    with armd.track(ARM, deadman=1.0) as t:  # (long enough to come back to the last target after it halts at speed)
        t.send(target=(centre + np.array([0.0, 0.05, 0.0])).tolist())
        time.sleep(1.0)
        sent = stream_circle(t, centre, 0.05, 0.2, 3.0)
        end = resting(arm_sim)
    within_limits(arm, arm_sim.commanded(), 1 / RATE)
    # the tool on the circle, after the first second (a lag of the way to the adapter: a few mm)
    S = np.array([s[0] for s in sent])
    X = np.array([s[1] for s in sent])
    with arm_sim.lock:
        run = [(t_, q) for t_, q in arm_sim.times if S[0] + 1.0 < t_ < S[-1]]
    err = [np.linalg.norm(arm.fk(q) - X[np.searchsorted(S, t_) - 1]) for t_, q in run]
    # on the circle (how near, on an idle machine and a busy one, is bench/track.py's to say: 1 mm
    # idle in this one process with the router, the service, the arm and the client; tens under
    # two busy processes, where trajectories come late and the arm brakes toward the goal)
    assert np.median(err) < 0.05, np.median(err)
    assert np.linalg.norm(arm.fk(end) - X[-1]) < 1e-4  # it ended on the last target
    statuses = {e.status for e in t.events}
    assert statuses <= {"started", "deadman"}, [e.message for e in t.events]


def test_the_deadman_brakes_the_arm_when_the_puts_stop(armd: ArmClient, arm_sim: Recorder) -> None:
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    with armd.track(ARM, deadman=0.1) as t:
        goal = q0 + np.array([1.0, 0.0, 0.0, 0.0, 0.0])  # far: seconds away at a fifth of the limits
        for _ in range(10):
            t.send(joints=goal.tolist(), speed=0.2)
            time.sleep(0.02)
        last = time.monotonic()
        rest = resting(arm_sim, settle=0.3)
        assert t.wait_for("deadman") is not None
    with arm_sim.lock:
        moving = [t_ for (t_, q), (_, q2) in zip(arm_sim.times, arm_sim.times[1:], strict=False) if np.any(q != q2)]
    stop_time = planning.plan_stop(
        arm, JointState(q0, arm.limits.velocity * np.array([1, 0, 0, 0, 0]), np.zeros(arm.nq))
    ).duration
    assert moving[-1] - last < 0.1 + stop_time + 0.1  # the deadman, braking, and the way
    assert abs(rest[0] - goal[0]) > 0.3  # braked short of the goal
    within_limits(arm, arm_sim.commanded(), 1 / RATE)


@pytest.mark.parametrize(
    "put",
    [
        b"not json",
        b"[1, 2]",
        b'{"seq": 0, "joints": [0, 0, 0, 0, 0]}',
        b'{"session": "x", "joints": [0, 0, 0, 0, 0]}',
        b'{"session": "x", "seq": 0}',
        b'{"session": "x", "seq": 0, "joints": [0, 0, 0, 0]}',
        b'{"session": "x", "seq": 0, "joints": [0, 0, 0, 0, 0], "target": [0.2, 0, 0.1]}',
        b'{"session": "x", "seq": 0, "target": [NaN, 0, 0.1]}',
        b'{"session": "x", "seq": 0, "target": [1e308, 0, 0.1]}',
        b'{"session": "x", "seq": 0.5, "target": [0.2, 0, 0.1]}',
        b'{"session": "x", "seq": true, "target": [0.2, 0, 0.1]}',
        b'{"session": "x", "seq": 0, "target": [0.2, 0, 0.1], "speed": 0}',
        b'{"session": "x", "seq": 0, "target": [0.2, 0, 0.1], "deadman": 5}',
        b'{"session": "x", "seq": 0, "target": [0.2, 0, 0.1], "dance": 1}',
        b'{"session": "x", "seq": 0, "velocity": [0, 0, 50]}',
        b'{"session": "x", "seq": 0, "joints": [0, 0, 0, 0, 0], "approach": "parallel"}',
        b'{"session": "x", "seq": 0, "target": [0.2, 0, 0.1], "orientation": [1, 0, 0, 0]}',
        b'{"session": "' + b"x" * 100 + b'", "seq": 0, "target": [0.2, 0, 0.1]}',
        b'{"session": "x", "seq": 0, "joints": [' + b"0," * 3000 + b"0]}",
    ],
)
def test_a_malformed_put_moves_nothing_and_says_why(
    armd: ArmClient, arm_sim: Recorder, served: tuple[str, Service], put: bytes
) -> None:
    events: list[dict[str, Any]] = []
    sub = armd.session.declare_subscriber(f"tr/{ARM}/events", lambda s: events.append(json.loads(s.payload.to_bytes())))
    try:
        tracker = served[1]._tracker(served[1].arms[ARM])
        assert tracker is not None
        refused = sum(n for (status, _), n in tracker.counts.items() if status == "bad_request")
        before = arm_sim.adapter.position.copy()
        armd.session.put(f"tr/{ARM}/track", put)
        # said (once a second at most, per reason: counted between)
        wait_for(
            lambda: sum(n for (status, _), n in tracker.counts.items() if status == "bad_request") > refused,
            5,
            "the refusal",
        )
        time.sleep(0.1)
        assert np.allclose(arm_sim.adapter.position, before)
        assert not arm_sim.ran
        assert armd.fk(ARM, robots.load(ARM).neutral).position is not None  # the service keeps serving
    finally:
        sub.undeclare()
    said = [e for e in events if e.get("status") == "bad_request"]
    assert all(e.get("message") and e.get("reason") for e in said)


def keep(track: Any, seconds: float, **put: Any) -> None:
    """Put the same target at 100 Hz for ``seconds`` (a stream that holds still)."""
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < seconds:
        track.send(**put)
        k += 1
        time.sleep(max(0.0, t0 + k / 100 - time.monotonic()))


def test_a_second_session_waits_and_seq_must_rise(armd: ArmClient, arm_sim: Recorder) -> None:
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    with armd.track(ARM, session="first") as one, armd.track(ARM, session="second") as two:
        keep(one, 0.3, joints=(q0 + 0.05).tolist())
        two.send(joints=(q0 - 0.3).tolist())
        keep(one, 0.7, joints=(q0 + 0.05).tolist())
        assert two.wait_for("busy") is not None
        rest = arm_sim.adapter.position.copy()
        one.seq = 0  # a replay
        one.send(joints=(q0 + 0.3).tolist())
        event = one.wait_for("bad_request")
        assert event is not None and event.reason == "seq"
        time.sleep(0.1)
        assert np.allclose(arm_sim.adapter.position, rest)
    assert np.allclose(rest, q0 + 0.05, atol=1e-6)


def test_stop_ends_the_session_and_a_move_takes_over(armd: ArmClient, arm_sim: Recorder) -> None:
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    with armd.track(ARM) as t:
        keep(t, 0.1, joints=(q0 + np.array([0.8, 0, 0, 0, 0])).tolist())
        armd.stop(ARM)
        assert t.wait_for("ended") is not None
        rest = resting(arm_sim)
        t.send(joints=(q0 - 0.3).tolist())  # after the stop: ignored
        wait_for(lambda: any(e.reason == "ended" for e in t.events), 5, "the put refused")
        time.sleep(0.2)
        assert np.allclose(arm_sim.adapter.position, rest)
    with armd.track(ARM) as t:
        keep(t, 0.1, joints=(q0 - np.array([0.8, 0, 0, 0, 0])).tolist())
        armd.move(ARM, q0.tolist(), wait=True)
        ended = t.wait_for("ended")
        assert ended is not None and "move" in ended.message
    assert np.allclose(resting(arm_sim), q0, atol=1e-6)


def test_out_of_reach_under_the_floor_and_jogging(armd: ArmClient, arm_sim: Recorder) -> None:
    arm = robots.load(ARM)
    home = arm.fk(arm.neutral)
    with armd.track(ARM) as t:
        keep(t, 2.0, target=[2.0, 0.0, 0.2])  # far out of reach: the closest point
        assert t.wait_for("unreachable") is not None
        out = arm_sim.adapter.position.copy()
        assert np.linalg.norm(arm.fk(out)) > np.linalg.norm(home)  # stretched toward it
        keep(t, 0.3, target=[0.2, 0.0, -0.3])  # under the floor: not followed
        assert t.wait_for("collision") is not None
        assert np.allclose(arm_sim.adapter.position, out, atol=1e-9)
        start = arm.fk(out)
        keep(t, 0.5, velocity=[0.0, 0.0, -0.05])  # jog: 0.05 m/s down for half a second
        keep(t, 0.5, velocity=[0.0, 0.0, 0.0])
        moved = arm.fk(arm_sim.adapter.position) - start
    assert moved[2] < -0.01 and abs(moved[1]) < 0.005, moved


def test_puts_at_5_khz_are_coalesced_and_the_service_keeps_serving(
    armd: ArmClient, arm_sim: Recorder, served: tuple[str, Service]
) -> None:
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    tracker = served[1]._tracker(served[1].arms[ARM])
    assert tracker is not None
    cycles = tracker.cycles
    with armd.track(ARM) as t:
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 0.5:  # 5,000 puts a second, on this clock (as many as a busy machine can)
            t.send(joints=(q0 + 0.2 * math.sin(n / 500)).tolist())
            n += 1
            while time.monotonic() < t0 + n / 5000:
                pass
        assert armd.ik(ARM, arm.fk(q0).tolist()).status == "ok"
        keep(t, 0.5, joints=q0.tolist())
    assert n >= 500 and tracker.cycles - cycles < n / 5  # (at most one a cycle period: the latest wins)
    within_limits(arm, arm_sim.commanded(), 1 / RATE)


def test_the_put_shape_is_checked_whole() -> None:
    from armd.service.track_message import parse

    arm = robots.load(ARM)
    put = parse(arm, b'{"session": "s", "seq": 3, "target": [0.2, 0, 0.1], "approach": "parallel", "speed": 0.5}')
    assert (put.mode, put.seq, put.speed) == ("target", 3, 0.5)
    with pytest.raises(BadRequest, match="goes with target"):
        parse(arm, b'{"session": "s", "seq": 3, "velocity": [0, 0, 0], "approach": "parallel"}')


# -- the example and the protocol's snippet ---------------------------------------------------------

ROOT = __import__("pathlib").Path(__file__).resolve().parent.parent


def test_the_example_and_the_protocols_snippet_draw_their_circles(router: str, service: Service) -> None:
    """examples/track_circle.py (ArmClient) and protocol.md's snippet (only eclipse-zenoh), as a
    user runs them, against the catalogue's service: the tool goes round, within every limit."""
    import re
    import subprocess
    import sys

    session = zenoh.open(network_config(connect=[router]))
    rec = Recorder(session, robots.load(ARM), "armd")
    try:
        wait_for(lambda: service.book.current(service.arms[ARM]).source == "adapter", 10, "the adapter's state")
        run = subprocess.run(
            [sys.executable, str(ROOT / "examples" / "track_circle.py"), ARM, "--connect", router],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert run.returncode == 0, run.stderr
        arm = robots.load(ARM)
        path = np.array([arm.fk(q) for _, q in rec.times])
        assert np.ptp(path[:, 1]) > 0.08 and np.ptp(path[:, 2]) > 0.08  # a circle 0.1 m across, round
        within_limits(arm, rec.commanded(), 1 / RATE)
        time.sleep(0.5)  # (the example's session: its deadman run out)
        snippet = re.search(r"### `armd/<robot>/track`.*?```python\n(.*?)```", DOC, flags=re.S)
        assert snippet is not None
        code = snippet.group(1).replace("tcp/127.0.0.1:7447", router)
        before = len(rec.times)
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        resting(rec)
        path = np.array([arm.fk(q) for _, q in rec.times[before:]])
        assert np.ptp(path[:, 1]) > 0.015  # (from where the example left it: the first part catches up)
        within_limits(arm, rec.commanded(), 1 / RATE)
    finally:
        rec.adapter.close()
        session.close()


DOC = (ROOT / "docs" / "protocol.md").read_text()


# -- the service or the adapter gone mid-stream ---------------------------------------------------


def _serving(armd: ArmClient) -> bool:
    try:
        armd.robots()
        return True
    except NoReply:
        return False


def test_a_service_killed_mid_stream_leaves_the_arm_braking_on_its_own(router: str, tmp_path: Any) -> None:
    """`armd serve` killed (SIGKILL) while a stream moves the arm: the adapter, which needs
    nothing from it, runs the last trajectory it has, which ends at rest where the deadman ran
    out: the arm rests within the deadman and a stop's braking, every limit kept."""
    import signal
    import subprocess
    import sys

    session = zenoh.open(network_config(connect=[router]))
    rec = Recorder(session, robots.load(ARM), "kill")
    serve = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", "serve", "--connect", router, "--prefix", "kill"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=(tmp_path / "serve.log").open("w"),
    )
    try:
        with ArmClient(router, prefix="kill", timeout=60.0) as armd:
            wait_for(lambda: _serving(armd), 120, "the service (its warm-up: seconds on a busy machine)")
            arm = robots.load(ARM)
            q0 = np.array(arm.neutral)
            with armd.track(ARM) as t:
                keep(t, 0.5, joints=q0.tolist())
                far = q0 + np.array([1.2, 0.0, 0.0, 0.0, 0.0])
                keep(t, 0.3, joints=far.tolist(), speed=0.2)  # (on its way: seconds from there, at a fifth)
                serve.send_signal(signal.SIGKILL)
                killed = time.monotonic()
                serve.wait(10)
                keep(t, 0.3, joints=far.tolist(), speed=0.2)  # (puts nobody hears)
            rest = resting(rec, settle=0.3)
        with rec.lock:
            moved = [t_ for (t_, q), (_, q2) in zip(rec.times, rec.times[1:], strict=False) if np.any(q != q2)]
        brake = planning.plan_stop(arm, JointState(q0, arm.limits.velocity * np.eye(arm.nq)[0], np.zeros(arm.nq)))
        assert moved[-1] - killed < 0.25 + brake.duration + 0.05  # the deadman, a stop's braking (and the way)
        assert abs(rest[0] - far[0]) > 0.2  # braked, short of the goal
        within_limits(arm, rec.commanded(), 1 / RATE)
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.wait(10)
        rec.adapter.close()
        session.close()


def test_an_adapter_gone_mid_stream_is_said_and_a_new_one_takes_the_stream_from_where_it_is(
    armd: ArmClient, served: tuple[str, Service]
) -> None:
    router, service = served
    arm = robots.load(ARM)
    q0 = np.array(arm.neutral)
    session = zenoh.open(network_config(connect=[router]))
    first = Recorder(session, arm, "tr")
    wait_for(lambda: service._adapter_count(service.arms[ARM]) == 1, 10, "the adapter")
    with armd.track(ARM, deadman=1.0) as t:
        keep(t, 0.3, joints=q0.tolist())
        keep(t, 0.2, joints=(q0 + 0.5).tolist())
        first.adapter.close()  # (the adapter gone mid-move: the simulated arm stays where it was)
        wait_for(lambda: service._adapter_count(service.arms[ARM]) == 0, 10, "the adapter gone")
        keep(t, 0.3, joints=(q0 + 0.5).tolist())
        assert t.wait_for("waiting") is not None  # no adapter: said, nothing sent
        second = Recorder(session, arm, "tr")  # a new one, where the arm is (its neutral: the sim starts there)
        try:
            wait_for(lambda: service._adapter_count(service.arms[ARM]) == 1, 10, "the new adapter")
            time.sleep(0.2)
            keep(t, 1.5, joints=(q0 + 0.5).tolist())
            assert np.allclose(resting(second), q0 + 0.5, atol=1e-6)  # the stream goes on, from where the arm is
            within_limits(arm, second.commanded(), 1 / RATE)
        finally:
            second.adapter.close()
    session.close()


# -- every field fuzzed: refused whole, never anything else -----------------------------------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=80),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=12),
    st.lists(st.integers(), max_size=8),
    st.dictionaries(st.text(max_size=8), st.integers(), max_size=3),
)
_FIELDS = st.sampled_from(
    (
        *("session", "seq", "joints", "target", "velocity", "approach", "roll", "orientation", "pitch_rate"),
        *("roll_rate", "speed", "gripper", "deadman", "time", "protocol", "dance", ""),
    )
)


@settings(max_examples=400, deadline=None)
@given(
    base=st.sampled_from(
        [
            {"session": "s", "seq": 1, "joints": [0.0, 1.5, -1.5, 0.0, 0.0]},
            {"session": "s", "seq": 1, "target": [0.25, 0.0, 0.1], "approach": "parallel"},
            {"session": "s", "seq": 1, "velocity": [0.0, 0.0, 0.01], "pitch_rate": 0.1},
        ]
    ),
    changes=st.dictionaries(_FIELDS, _VALUES, min_size=1, max_size=3),
)
def test_a_fuzzed_put_is_a_track_put_or_a_bad_request_and_nothing_else(
    base: dict[str, Any], changes: dict[str, Any]
) -> None:
    """Any field, any value (wrong types, NaN, 1e308, 2^70, huge lists, unknown names): the put
    is read whole into a :class:`TrackPut` within its bounds, or refused with a
    :class:`BadRequest` naming a field; no other exception, nothing half-read."""
    import json

    from armd.service.track_message import MAX_SEQ, TrackPut, parse

    arm = robots.load(ARM)
    put = {**base, **changes}
    try:
        payload = json.dumps(put, allow_nan=True).encode()
    except (ValueError, OverflowError):
        return
    try:
        got = parse(arm, payload)
    except BadRequest as e:
        assert e.message and e.fields.get("field") is not None
        return
    assert isinstance(got, TrackPut)
    assert got.mode in ("joints", "target", "velocity") and 0 <= got.seq <= MAX_SEQ
    assert np.all(np.isfinite(got.value)) and len(got.value) == (arm.nq if got.mode == "joints" else 3)
    assert got.speed is None or 0.0 < got.speed <= 1.0
    assert got.gripper is None or 0.0 <= got.gripper <= 1.0
    assert got.deadman is None or 0.05 <= got.deadman <= 1.0
