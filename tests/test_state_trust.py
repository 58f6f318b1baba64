"""Whom the service believes: states only from live adapters, in order and plausible; a move
succeeds only once an adapter accepted its trajectory. Through real Zenoh sessions on a router."""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import ServiceError
from armd.service.server import ACCEPT_TIMEOUT, DISPUTE_HOLD
from armd.service.zconfig import network_config
from tests.conftest import collect, wait_for

ARM = "desk4"


@pytest.fixture
def forger(router: str) -> Iterator[zenoh.Session]:
    """Someone else on the network, with no adapter behind them."""
    session = zenoh.open(network_config(connect=[router]))
    yield session
    session.close()


def _state(q: list[float], adapter: str, seq: int, **extra: object) -> bytes:
    n = len(q)
    return json.dumps(
        {
            "robot": ARM,
            "adapter": adapter,
            "seq": seq,
            "position": q,
            "velocity": [0.0] * n,
            "acceleration": [0.0] * n,
            "moving": False,
            "homed": True,
            **extra,
        }
    ).encode()


def _ignored(service: object) -> int:
    return int(service.stats()["states_ignored"])  # type: ignore[attr-defined]


def test_a_state_from_no_live_adapter_is_ignored_and_counted(
    client: ArmClient, service: object, forger: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    far = (np.array(arm.neutral) + 0.5).tolist()
    before = _ignored(service)
    for seq in range(50):  # faster than any adapter
        forger.put(f"armd/{ARM}/state", _state(far, "forged00001", seq))
        time.sleep(0.002)
    wait_for(lambda: _ignored(service) >= before + 50, what="the forged states counted")
    s = client.state(ARM)
    assert s["source"] != "adapter" and not np.allclose(s["position"], far)


def test_ignored_states_are_logged_at_a_bounded_rate_with_their_reasons(
    client: ArmClient, service: object, forger: zenoh.Session, caplog: pytest.LogCaptureFixture
) -> None:
    """A forger's flood is counted, not logged message by message: at most one line every
    SAY_EVERY seconds, saying how many were ignored and why."""
    caplog.set_level(logging.WARNING, logger="armd.service.server")
    service._said = 0.0  # type: ignore[attr-defined]  # (another test may have just logged)
    before = _ignored(service)
    for seq in range(200):
        forger.put(f"armd/{ARM}/state", _state(list(robots.load(ARM).neutral), "forged00002", seq))
    forger.put(f"armd/{ARM}/state", b"not json")
    wait_for(lambda: _ignored(service) >= before + 201, what="the flood counted")
    lines = [r.getMessage() for r in caplog.records if "ignoring states" in r.getMessage()]
    assert len(lines) == 1, lines  # 201 ignored in well under SAY_EVERY: one line
    assert "no live adapter of that id" in lines[0] and f"armd/{ARM}/state" in lines[0]


def test_a_live_adapters_state_is_used_and_forgeries_beside_it_are_not(
    client: ArmClient, service: object, adapter_session: zenoh.Session, forger: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    start = (np.array(arm.neutral) + 0.1).tolist()
    adapter = SimAdapter(adapter_session, arm, start=np.array(start))
    try:
        wait_for(
            lambda: (
                client.state(ARM)["source"] == "adapter"
                and np.allclose(client.state(ARM)["position"], start, atol=1e-9)
            ),
            what="the adapter's state",
        )
        before = _ignored(service)
        far = (np.array(arm.neutral) - 0.6).tolist()
        outside = (np.array(arm.limits.upper) + 0.5).tolist()
        # its id (it is in every state it publishes), but a jump, a replay, a pose outside the
        # limits, a speed over them, a malformed number: none is believed
        forger.put(f"armd/{ARM}/state", _state(far, adapter.id, 10**9))
        forger.put(f"armd/{ARM}/state", _state(start, adapter.id, 0))
        forger.put(f"armd/{ARM}/state", _state(outside, adapter.id, 10**9 + 1))
        forger.put(
            f"armd/{ARM}/state", _state(start, adapter.id, 10**9 + 2, velocity=(arm.limits.velocity * 10).tolist())
        )
        forger.put(f"armd/{ARM}/state", b'{"adapter": "x", "seq": 1, "position": [1e999]}')
        wait_for(lambda: _ignored(service) >= before + 5, what="the forgeries ignored")
        for _ in range(10):  # the replay disputes the id: its last believed report, or none
            s = client.state(ARM)
            assert s["source"] != "adapter" or np.allclose(s["position"], start, atol=1e-9), s
            time.sleep(0.02)
        # the adapter's own reports, in order, are believed again once the dispute is over
        wait_for(lambda: client.state(ARM)["source"] == "adapter", timeout=DISPUTE_HOLD + 5, what="the adapter again")
        assert np.allclose(client.state(ARM)["position"], start, atol=1e-9)
        # and a move plans from where the adapter says the arm is
        r = client.call(f"{ARM}/move", {"goal": list(arm.neutral)})
        assert np.allclose(r["start"]["position"], start, atol=1e-6) and r["adapter"] == adapter.id
    finally:
        adapter.close()


def test_a_forger_numbering_ahead_of_the_adapter_neither_steers_nor_locks_it_out(
    client: ArmClient, service: object, adapter_session: zenoh.Session, forger: zenoh.Session
) -> None:
    """The adapter's id and the arm's pose are public (in every report): a forger sends the pose
    numbered far ahead, then walks it away within the velocity limits. Believed, that first
    report would make every real report look old (the adapter locked out) and the walk would be
    the service's picture of the arm. The adapter's next report, numbered lower, disputes the id:
    the walk is never believed, and once the forger stops the adapter is believed again."""
    arm = robots.load(ARM)
    start = (np.array(arm.neutral) + 0.1).tolist()
    adapter = SimAdapter(adapter_session, arm, start=np.array(start))
    try:
        wait_for(lambda: client.state(ARM)["source"] == "adapter", what="the adapter's state")
        seen: list[dict[str, object]] = []
        step = arm.limits.velocity * 0.02 * 0.5  # half the speed limit, at 50 Hz
        q = np.array(start)
        for i in range(60):
            q = q + step * (1 if i else 0)
            forger.put(f"armd/{ARM}/state", _state(q.tolist(), adapter.id, 2**62 + i))
            seen.append(client.state(ARM))
            time.sleep(0.02)
        for s in seen:  # never the walk: the adapter's pose, or (disputed, stale) not an adapter's word
            assert s["source"] != "adapter" or np.allclose(s["position"], start, atol=1e-9), s
        wait_for(lambda: client.state(ARM)["source"] == "adapter", timeout=DISPUTE_HOLD + 5, what="the adapter again")
        assert np.allclose(client.state(ARM)["position"], start, atol=1e-9)
    finally:
        adapter.close()


def test_stop_and_move_are_answered_while_forged_states_pour_in(
    client: ArmClient, service: object, adapter_session: zenoh.Session, forger: zenoh.Session
) -> None:
    """The issue's forger at 500 Hz, out of the limits, over the speed limits, 1e308, under the
    live adapter's id and under none: every stop and move is still answered, and the move
    starts where the adapter says the arm is (before, each answered bad_request)."""
    arm = robots.load(ARM)
    start = (np.array(arm.neutral) + 0.1).tolist()
    adapter = SimAdapter(adapter_session, arm, start=np.array(start))
    stop = threading.Event()
    outside = (np.array(arm.limits.upper) + 0.5).tolist()
    fast = (arm.limits.velocity * 10).tolist()

    def pour() -> None:
        seq = 10**6
        while not stop.is_set():
            seq += 1
            for who in (adapter.id, "nobody000001"):
                forger.put(f"armd/{ARM}/state", _state(outside, who, seq))
                forger.put(f"armd/{ARM}/state", _state(start, who, seq + 1, velocity=fast))
                forger.put(f"armd/{ARM}/state", _state([1e308] * arm.nq, who, seq + 2))
            seq += 2
            time.sleep(0.002)

    thread = threading.Thread(target=pour, daemon=True)
    try:
        wait_for(lambda: client.state(ARM)["source"] == "adapter", what="the adapter's state")
        thread.start()
        time.sleep(0.2)
        for _ in range(3):
            client.stop(ARM)  # answered, never bad_request
            s = client.state(ARM)
            assert s["source"] != "adapter" or np.allclose(s["position"], start, atol=1e-9), s
        # a move meanwhile: planned from what the service has, refused by the adapter where that
        # is not where the arm is, planned again from the adapter's word
        r = client.call(f"{ARM}/move", {"goal": (np.array(start) + 0.05).tolist()})
        assert np.allclose(r["start"]["position"], start, atol=1e-6) and r["adapter"] == adapter.id
        client.call(f"{ARM}/stop", {})
        stop.set()
        thread.join()
        wait_for(lambda: client.state(ARM)["source"] == "adapter", timeout=DISPUTE_HOLD + 5, what="the adapter again")
        wait_for(lambda: not client.state(ARM)["moving"], what="the arm at rest")
        here = client.state(ARM)["position"]
        r = client.call(f"{ARM}/move", {"goal": list(arm.neutral)})
        assert r["adapter"] == adapter.id and np.allclose(r["start"]["position"], here, atol=1e-6)
    finally:
        stop.set()
        adapter.close()


def test_a_gone_adapters_state_is_forgotten(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load(ARM)
    adapter = SimAdapter(adapter_session, arm)
    wait_for(lambda: client.state(ARM)["source"] == "adapter", what="the adapter's state")
    adapter.close()
    wait_for(lambda: service._adapter_count(arm) == 0, what="the token gone")  # type: ignore[attr-defined]
    assert client.state(ARM)["source"] != "adapter"


def test_a_token_alone_does_not_make_a_move_succeed(client: ArmClient, service: object, forger: zenoh.Session) -> None:
    """A liveliness token with nothing behind it: the move waits for an acceptance that never
    comes, answers no_adapter, and sends an estop so that a late adapter does not move the arm."""
    arm = robots.load(ARM)
    token = forger.liveliness().declare_token(f"armd/{ARM}/adapter/faketoken01")
    estops, sub = collect(client, f"armd/{ARM}/estop")
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the fake token")  # type: ignore[attr-defined]
        asked = time.monotonic()
        with pytest.raises(ServiceError) as e:
            client.move(ARM, (np.array(arm.neutral) + 0.2).tolist())
        assert e.value.code == "no_adapter" and "accepted" in e.value.message
        assert time.monotonic() - asked >= ACCEPT_TIMEOUT * 0.9
        wait_for(lambda: len(estops) >= 1, what="the estop")
        assert "no adapter accepted" in str(estops[-1].get("reason"))
    finally:
        sub.undeclare()  # type: ignore[attr-defined]
        token.undeclare()


def test_a_move_names_the_adapter_that_accepted_it(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    adapter = SimAdapter(adapter_session, arm)
    try:
        wait_for(lambda: client.state(ARM)["source"] == "adapter", what="the adapter's state")
        reply = client.move(ARM, (np.array(arm.neutral) + 0.1).tolist())
        assert reply.adapter == adapter.id
    finally:
        adapter.close()


def test_a_move_planned_from_a_late_report_is_planned_again_from_the_adapters_word(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """The service's picture of the arm is only as fresh as the last report (late on a loaded
    machine; here an adapter that reports about once a second). A move planned from an old
    report is refused by the adapter (`start_mismatch`, with where the arm is); the service plans
    it once more from there, and the move succeeds, starting where the arm is."""
    arm = robots.load(ARM)
    adapter = SimAdapter(adapter_session, arm, state_hz=1.15)
    events, sub = collect(client, f"armd/{ARM}/events")
    goals = [(np.array(arm.neutral) + d * np.eye(arm.nq)[0]).tolist() for d in (0.8, -0.8)]
    try:
        wait_for(lambda: client.state(ARM)["source"] == "adapter", what="the adapter's state")
        for attempt in range(6):  # until the last report before arrival was taken on the way
            goal = goals[attempt % 2]
            first = client.move(ARM, goal)
            wait_for(
                lambda i=first.id: any(e.get("event") == "done" and e.get("id") == i for e in events),
                what="the first move done",
            )
            believed = client.state(ARM)
            if believed["source"] == "adapter" and not np.allclose(believed["position"], goal, atol=0.05):
                break
        else:
            pytest.fail("every report came after arrival: the test measured nothing")
        second = client.call(f"{ARM}/move", {"goal": goals[(attempt + 1) % 2]})
        assert np.allclose(second["start"]["position"], goal, atol=0.03)  # (where the arm is, not the old report)
        refused = [e for e in events if e.get("event") == "rejected" and e.get("id") != second["id"]]
        assert refused and refused[-1]["error"]["code"] == "start_mismatch"  # type: ignore[index]
        assert np.allclose(refused[-1]["error"]["state"]["position"], goal, atol=0.03)  # type: ignore[index]
        wait_for(
            lambda: any(e.get("event") == "accepted" and e.get("id") == second["id"] for e in events),
            what="the second plan accepted",
        )
    finally:
        sub.undeclare()  # type: ignore[attr-defined]
        adapter.close()


def test_the_same_message_twice_is_a_double_delivery_not_a_dispute(
    client: ArmClient, service: object, forger: zenoh.Session
) -> None:
    """Zenoh may deliver one put twice (two routes): the very same message again is dropped;
    another message under the same number disputes the id."""
    arm = robots.load(ARM)
    token = forger.liveliness().declare_token(f"armd/{ARM}/adapter/twice0000001")
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the token")  # type: ignore[attr-defined]
        here = (np.array(arm.neutral) + 0.05).tolist()
        first = _state(here, "twice0000001", 1)
        for _ in range(2):
            forger.put(f"armd/{ARM}/state", first)
        time.sleep(0.2)
        forger.put(f"armd/{ARM}/state", _state(here, "twice0000001", 2))
        wait_for(lambda: service.book.last(ARM, "twice0000001") is not None, what="believed")  # type: ignore[attr-defined]
        assert client.state(ARM)["source"] == "adapter"
        forger.put(f"armd/{ARM}/state", _state((np.array(here) + 0.01).tolist(), "twice0000001", 2))
        wait_for(lambda: service.book.last(ARM, "twice0000001") is None, what="the dispute")  # type: ignore[attr-defined]
    finally:
        token.undeclare()


def test_an_unlock_is_believed_at_once(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    """GRBL's position unknown until an operator says the arm is at rest: the unlock moves the
    state by the rest pose's offset (a jump), in a new epoch the service believes at once, so a
    move sent on the adapter's ``unlocked`` is planned from there and runs (the old service
    ignored the jump as not continuous for 0.5 s and refused the move ``position_unknown``)."""
    from armd.adapters.emulators.grbl import GrblEmulator
    from armd.adapters.grbl import GrblAdapter

    arm = robots.load("gupta3")
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            wait_for(lambda: client.state("gupta3").get("homed") is False, what="the position unknown")
            epoch = adapter.epoch
            answer = client.unlock("gupta3", "assume_rest", wait=10)
            assert answer is not None and answer["event"] == "unlocked", answer
            assert adapter.epoch == epoch + 1
            r = client.move("gupta3", [0.3, 1.1, -1.2], wait=True, wait_timeout=20)  # at once: no wait for a state
            assert r.start_source == "adapter"
        finally:
            adapter.close()
