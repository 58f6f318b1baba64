"""Whom ``detect`` believes: range readings only from the arm's live adapter, in order (``seq``),
plausible (a range within the sensor's, a time near now), a sensor two publishers use disputed
(``not_ready``, never an answer on mixed readings), the reply naming the adapter whose readings
it rests on. Through real Zenoh sessions on a router (issue 34, finding 3)."""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import ArmdError
from armd.service.server import DISPUTE_HOLD  # (the sensors' hold is the states': service/sensor_book.py)
from armd.service.zconfig import network_config
from tests.conftest import wait_for

ARM = "insomniac"
LEFT = "et_left"
DISPUTED = "numbered out of order, or a second adapter: the sensor disputed"  # (the book's count of it)
BLOCK = zenoh.CongestionControl.BLOCK  # (a burst of readings is never dropped on the way)


@pytest.fixture
def forger(router: str) -> Iterator[zenoh.Session]:
    """Someone else on the network: a session of its own, maybe with an adapter's stolen password."""
    session = zenoh.open(network_config(connect=[router]))
    yield session
    session.close()


def _ignored(service: Any, why: str) -> int:
    return int(service.sensor_book.ignored.get(why, 0))


def _bearings(sensor: Any) -> list[float]:
    lo, hi = sensor.sweep
    n = round((hi - lo) / sensor.sweep_step)
    return [lo + k * (hi - lo) / n for k in range(n + 1)]


class Hand:
    """Readings of ``sensor`` made by hand under adapter id ``ident``, on a publisher of
    ``session``'s (with that id's liveliness token if ``token``): what an adapter, or a
    forger who has an adapter's password or its public id, can put."""

    def __init__(self, session: zenoh.Session, sensor: str = LEFT, ident: str = "", token: bool = True) -> None:
        self.id = ident or uuid.uuid4().hex[:12]
        self.sensor = robots.load(ARM).sensors[sensor]
        self.pub = session.declare_publisher(f"armd/{ARM}/sensors/{sensor}", congestion_control=BLOCK)
        self.token = session.liveliness().declare_token(f"armd/{ARM}/adapter/{self.id}") if token else None
        self.seq = 0

    def put(self, bearing: float, rng: float | None, sweep: int, **extra: Any) -> bytes:
        self.seq += 1
        msg = {
            "sensor": self.sensor.name,
            "model": self.sensor.model,
            "time": time.time(),
            "adapter": self.id,
            "seq": self.seq,
            "volts": 1.0,
            "range": rng,
            "bearing": round(bearing, 6),
            "sweep": sweep,
            "direction": 1 if sweep % 2 == 0 else -1,
            **extra,
        }
        payload = json.dumps(msg).encode()
        self.pub.put(payload)
        return payload

    def sweep(self, k: int, seen: tuple[float, float] | None = (0.0, 0.12), rng: float = 0.30, **extra: Any) -> None:
        """Sweep ``k`` (the way its count says), an object at range ``rng`` between the bearings
        ``seen`` (None: nothing in range); ``extra`` fields on the object's readings."""
        self.objects(k, [] if seen is None else [(seen, rng)], **extra)

    def objects(self, k: int, objects: list[tuple[tuple[float, float], float]], **extra: Any) -> None:
        """Sweep ``k`` showing ``objects``, each (its bearings [rad], its range [m])."""
        bearings = _bearings(self.sensor)
        for b in bearings if k % 2 == 0 else bearings[::-1]:
            rng = next((r for (lo, hi), r in objects if lo <= b <= hi), None)
            self.put(b, rng, k, **(extra if rng is not None else {}))

    def close(self) -> None:
        if self.token is not None:
            self.token.undeclare()
        self.pub.undeclare()


def _detect(client: ArmClient, **req: Any) -> dict[str, Any]:
    return client.call(f"{ARM}/detect", {"sensors": [LEFT], "sweeps": 2, "deadline": 3.0, **req})


def _refused(client: ArmClient) -> ArmdError:
    with pytest.raises(ArmdError) as e:
        _detect(client)
    return e.value


def _settled(service: Any) -> None:
    """Until no dispute of the sensor is left from a test before (its ids gone, it ends)."""
    wait_for(lambda: service._adapter_count(robots.load(ARM)) == 0, what="no adapter of the arm left")


def test_detect_names_the_adapter_whose_readings_it_rests_on(
    client: ArmClient, service: Any, forger: zenoh.Session
) -> None:
    _settled(service)
    hand = Hand(forger)
    try:
        wait_for(lambda: service._adapter_count(robots.load(ARM)) == 1, what="its token")
        for k in range(4):
            hand.sweep(k)
        hand.put(0.0, None, 4)  # (sweep 3 complete)
        r = _detect(client)
        (seen,) = r["objects"]
        assert seen["stable"] and abs(seen["range"] - 0.30) < 1e-9
        assert r["adapters"] == [hand.id]
    finally:
        hand.close()


def test_readings_under_an_id_with_no_live_token_are_ignored(
    client: ArmClient, service: Any, adapter_session: zenoh.Session, forger: zenoh.Session
) -> None:
    """A forger with no adapter's password: no token of its own; its readings under an id that
    no live adapter has (a made-up one, or an adapter's that is gone) change nothing."""
    _settled(service)
    real = Hand(adapter_session)
    nobody = Hand(forger, token=False)
    try:
        wait_for(lambda: service._adapter_count(robots.load(ARM)) == 1, what="the adapter's token")
        before = _ignored(service, "no live adapter of that id")
        for k in range(4):
            real.sweep(k, seen=None)
            nobody.sweep(k)
        real.put(0.0, None, 4)
        nobody.put(0.0, None, 4)
        n = 4 * len(_bearings(real.sensor)) + 1
        wait_for(lambda: _ignored(service, "no live adapter of that id") >= before + n, what="ignored")
        r = _detect(client)
        assert r["objects"] == [] and r["adapters"] == [real.id]
    finally:
        nobody.close()
        real.close()


def test_readings_numbered_out_of_order_dispute_the_sensor(
    client: ArmClient, service: Any, adapter_session: zenoh.Session
) -> None:
    """One publisher's numbers only rise: a reading numbered back (here the adapter's own
    session, as a second publisher's would) is not used, and the sensor is disputed:
    ``not_ready`` naming it, until one publisher alone has numbered in order for the hold."""
    _settled(service)
    hand = Hand(adapter_session)
    try:
        wait_for(lambda: service._adapter_count(robots.load(ARM)) == 1, what="its token")
        for k in range(4):
            hand.sweep(k)
        hand.put(0.0, None, 4)
        assert _detect(client)["objects"]
        before = _ignored(service, DISPUTED)
        hand.seq -= 10  # numbered back: another publisher under the id, or a replay
        hand.put(0.5, 0.2, 4)
        wait_for(lambda: _ignored(service, DISPUTED) > before, what="the reading numbered back")
        e = _refused(client)
        assert e.code == "not_ready" and e.fields.get("disputed") == [LEFT], e
        assert e.fields.get("adapters") == [hand.id] and "disputed" in e.message
        hand.seq += 10
        time.sleep(DISPUTE_HOLD + 0.2)  # in order again for the hold: believed again, afresh
        for k in range(4, 8):
            hand.sweep(k)
        hand.put(0.0, None, 8)
        r = _detect(client)
        assert r["objects"] and r["adapters"] == [hand.id]
    finally:
        hand.close()


def test_the_same_reading_twice_is_a_double_delivery_not_a_dispute(
    client: ArmClient, service: Any, adapter_session: zenoh.Session
) -> None:
    _settled(service)
    hand = Hand(adapter_session)
    try:
        wait_for(lambda: service._adapter_count(robots.load(ARM)) == 1, what="its token")
        for k in range(4):
            hand.sweep(k)
            if k == 2:  # (Zenoh may deliver one put twice, over two routes): in the sweeps looked at
                hand.pub.put(hand.put(0.99, None, k))
        hand.put(0.0, None, 4)
        r = _detect(client)
        assert r["objects"] and r["adapters"] == [hand.id]
    finally:
        hand.close()


@pytest.mark.parametrize(
    "extra, why",
    [
        (
            {"time_shift": 3600.0},
            "a time far from the service's clock",
        ),  # far in the future (5 s allowed)
        ({"time_shift": -3600.0}, "a time far from the service's clock"),  # an old reading replayed
        ({"range": 5.0}, "a range outside the sensor's"),  # beyond what the GP2D12 reads
    ],
)
def test_implausible_readings_are_ignored(
    client: ArmClient, service: Any, adapter_session: zenoh.Session, extra: dict[str, float], why: str
) -> None:
    """The object's readings, each implausible: none is used, the rest of the sweeps are."""
    _settled(service)
    hand = Hand(adapter_session)
    try:
        wait_for(lambda: service._adapter_count(robots.load(ARM)) == 1, what="its token")
        before = _ignored(service, why)
        shift = extra.get("time_shift")
        bad = {"time": time.time() + shift} if shift is not None else {}
        for k in range(4):
            hand.sweep(k, rng=extra.get("range", 0.30), **bad)
        hand.put(0.0, None, 4)
        r = _detect(client)
        assert r["objects"] == [] and r["adapters"] == [hand.id]
        on = sum(0.0 <= b <= 0.12 for b in _bearings(hand.sensor))  # (the object's readings in a sweep)
        assert on >= 2 and _ignored(service, why) >= before + 4 * on
    finally:
        hand.close()


class Flood:
    """The issue's forger: it watches the live adapter's readings (public) for its id and its
    sweep count, and puts whole sweeps showing two objects that are not there, numbered ahead,
    as fast as it can, on ``session`` (another session than the adapter's), under ``ident``
    (the live adapter's own, or a token of its own: an adapter's stolen password)."""

    def __init__(self, session: zenoh.Session, real: str, ident: str = "", token: bool = False) -> None:
        self.real = real
        self.count = -1  # the adapter's sweep count, as last seen
        self.sub = session.declare_subscriber(f"armd/{ARM}/sensors/{LEFT}", self._on)
        self.hand = Hand(session, ident=ident or real, token=token)
        self.hand.seq = 10**9
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.sent = 0

    def _on(self, sample: zenoh.Sample) -> None:
        msg = json.loads(sample.payload.to_bytes())
        if msg.get("adapter") == self.real and msg.get("seq", 0) < 10**9:
            self.count = max(self.count, int(msg["sweep"]))

    def _run(self) -> None:
        k = -1
        while not self.stop.is_set():
            if self.count < 0:
                time.sleep(0.01)
                continue
            k = max(k + 1, self.count + 1)  # ahead of the adapter's count, and on
            self.hand.objects(k, [((-0.5, -0.38), 0.30), ((0.3, 0.42), 0.45)])  # two objects
            self.sent += len(_bearings(self.hand.sensor))
            time.sleep(0.002)

    def __enter__(self) -> Flood:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join()
        self.hand.close()
        self.sub.undeclare()


def _watch_detect(client: ArmClient, seconds: float) -> tuple[list[dict[str, Any]], list[ArmdError]]:
    answers: list[dict[str, Any]] = []
    refusals: list[ArmdError] = []
    until = time.monotonic() + seconds
    while time.monotonic() < until:
        try:
            answers.append(_detect(client, deadline=1.0))
        except ArmdError as e:
            refusals.append(e)
        time.sleep(0.05)
    return answers, refusals


@pytest.mark.parametrize("own_token", [False, True], ids=["under-the-adapters-id", "a-token-of-its-own"])
def test_a_forgers_flood_never_steers_detect_and_disputes_the_sensor(
    client: ArmClient, service: Any, adapter_session: zenoh.Session, forger: zenoh.Session, own_token: bool
) -> None:
    """A simulated arm on an empty floor; the forger floods whole sweeps of two objects that
    are not there from another session, under the live adapter's public id (or, with a stolen
    password, under a token of its own). Before, detect reported them. Now no answer shows
    one: detect is ``not_ready`` naming the dispute; once the forger stops, the adapter's own
    readings are believed again and detect names it."""
    _settled(service)
    arm = robots.load(ARM)
    sim = SimAdapter(adapter_session, arm, time_scale=10.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        assert client.detect(ARM, sensors=[LEFT], wait=10.0)["objects"] == []
        with Flood(forger, sim.id, ident=uuid.uuid4().hex[:12] if own_token else "", token=own_token) as flood:
            wait_for(lambda: flood.sent >= 2000, what="the flood under way")
            answers, refusals = _watch_detect(client, 3.0)
            sent = flood.sent
        assert sent >= 2000
        phantoms = [o for a in answers for o in a["objects"]]  # (the floor is empty)
        assert not phantoms, f"{len(answers)} answers showed {len(phantoms)} objects after {sent} forged readings"
        disputed = [e for e in refusals if e.code == "not_ready" and e.fields.get("disputed") == [LEFT]]
        assert disputed, refusals
        assert sim.id in disputed[0].fields["adapters"]
        assert all(a["adapters"] == [sim.id] for a in answers), answers
        answer = client.detect(ARM, sensors=[LEFT], wait=DISPUTE_HOLD + 10.0)
        assert answer["objects"] == [] and answer["adapters"] == [sim.id]
    finally:
        sim.close()
