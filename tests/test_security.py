"""docs/security: a router that authenticates every session and lets only trusted users move
arms. A guest's move is refused and nothing moves; an operator's works. And TLS, alone and
with the login and the ACL, with a throwaway CA made at test time."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from armd import robots, solvers
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import NoReply
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import free_port, wait_for

DOCS = Path(__file__).resolve().parent.parent / "docs" / "security"


def _copy(name: str, tmp: Path, port: int, as_name: str | None = None, **replace: str) -> Path:
    text = (DOCS / name).read_text().replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
    for old, new in replace.items():
        text = text.replace(old, new)
    out = tmp / (as_name or name)
    out.write_text(text)
    return out


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[dict[str, Path]]:
    port = free_port()
    router_conf = _copy("router.json5", tmp_path, port, **{"docs/security/users.txt": str(DOCS / "users.txt")})
    router = zenoh.open(zenoh.Config.from_file(str(router_conf)))
    sides = ("service", "operator", "guest", *(f"adapter-{name}" for name in robots.names()))
    confs = {who: _copy(f"{who}.json5", tmp_path, port) for who in sides}
    confs["intruder"] = _copy(
        "guest.json5", tmp_path, port, "intruder.json5", **{'password: "guest"': 'password: "wrong"'}
    )
    yield confs
    router.close()


def test_only_trusted_users_move_arms(secured: dict[str, Path]) -> None:
    arm = robots.load("gupta3")
    svc_session = zenoh.open(network_config(config_file=str(secured["service"])))
    service = Service(svc_session, {"gupta3": arm})
    adapter_session = zenoh.open(network_config(config_file=str(secured["adapter-gupta3"])))
    sim = SimAdapter(adapter_session, arm, time_scale=5.0)
    guest = ArmClient(config=str(secured["guest"]), timeout=2.0)
    operator = ArmClient(config=str(secured["operator"]), timeout=5.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")  # type: ignore[attr-defined]
        start = sim.position.copy()
        # the adapter's state reaches the service (its user may put its arm's state, and see that
        # the service follows every arm's)
        wait_for(lambda: operator.state("gupta3")["source"] == "adapter", what="the adapter's state")
        # read-only verbs are open to a guest
        assert guest.ik("gupta3", arm.fk(np.array([0.2, 1.0, -1.1])).tolist()).status == "ok"
        assert [r["name"] for r in guest.robots()] == ["gupta3"]
        # a guest's move is refused: the router drops it, the service never sees it
        with pytest.raises(NoReply) as refused:
            guest.move("gupta3", [0.5, 1.2, -1.0])
        assert "access-control list" in refused.value.message  # refused at once, and said so
        with pytest.raises(NoReply):
            guest.stop("gupta3")
        # and a guest cannot publish a trajectory to the adapter either
        traj = operator.plan("gupta3", [0.5, 1.2, -1.0], start=start)
        guest.session.put(
            "armd/gupta3/trajectory",
            b'{"robot": "gupta3", "id": "x", "rate_hz": 50, "times": [0.0],'
            b' "position": [[0.5, 1.2, -1.0]], "velocity": [[0, 0, 0]], "acceleration": [[0, 0, 0]]}',
        )
        time.sleep(0.5)
        assert np.allclose(sim.position, start) and service.stats()["served"] >= 1
        # an operator's move works
        operator.move("gupta3", traj.position[-1].tolist(), wait=True, wait_timeout=10)
        assert np.allclose(sim.position, [0.5, 1.2, -1.0], atol=1e-9)
    finally:
        guest.close()
        operator.close()
        sim.close()
        adapter_session.close()
        service.close()
        svc_session.close()


def test_a_wrong_password_cannot_connect(secured: dict[str, Path]) -> None:
    with pytest.raises(NoReply) as e:
        ArmClient(config=str(secured["intruder"]), timeout=1.0)
    assert "cannot reach" in e.value.message


# -- TLS -------------------------------------------------------------------------------------------


def _tls(
    name: str, tmp: Path, certs: Path, tls_port: int, tcp_port: int, as_name: str | None = None, **replace: str
) -> Path:
    """A copy of a docs/security file on free ports, its certificate paths pointing at ``certs``."""
    return _copy(
        name,
        tmp,
        tcp_port,
        as_name,
        **{"tls/127.0.0.1:7448": f"tls/127.0.0.1:{tls_port}", '"certs/': f'"{certs}/', **replace},
    )


def test_tls(tmp_path: Path, certs: Path) -> None:
    """docs/security/tls-*.json5: the service and a client over TLS, an adapter on loopback TCP;
    a client that does not trust the CA, or that speaks plain TCP to the TLS port, gets nowhere."""
    tls_port, tcp_port = free_port(), free_port()
    router = zenoh.open(zenoh.Config.from_file(str(_tls("tls-router.json5", tmp_path, certs, tls_port, tcp_port))))
    conf = _tls("tls-client.json5", tmp_path, certs, tls_port, tcp_port)
    arm = robots.load("gupta3")
    svc_session = zenoh.open(network_config(config_file=str(conf)))
    service = Service(svc_session, {"gupta3": arm})
    adapter_session = zenoh.open(network_config(connect=[f"tcp/127.0.0.1:{tcp_port}"]))
    sim = SimAdapter(adapter_session, arm, time_scale=5.0)
    client = ArmClient(config=str(conf), timeout=5.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")  # type: ignore[attr-defined]
        target = arm.fk(np.array([0.2, 1.0, -1.1]))
        r = client.ik("gupta3", target.tolist())
        assert r.status == "ok" and np.allclose(r.q, solvers.solve_ik(arm, target).q, atol=1e-12)
        client.move("gupta3", [0.4, 1.1, -1.2], wait=True, wait_timeout=10)
        assert np.allclose(sim.position, [0.4, 1.1, -1.2], atol=1e-9)
        untrusting = _tls(
            "tls-client.json5",
            tmp_path,
            certs,
            tls_port,
            tcp_port,
            "untrusting.json5",
            **{f'root_ca_certificate: "{certs}/ca.pem"': "verify_name_on_connect: true"},
        )
        with pytest.raises(NoReply):  # the system's CAs do not know this router
            ArmClient(config=str(untrusting), timeout=1.0)
        with pytest.raises(NoReply):  # TCP to the TLS port: no Zenoh session opens
            ArmClient(f"tcp/127.0.0.1:{tls_port}", timeout=1.0).robots()
    finally:
        client.close()
        sim.close()
        adapter_session.close()
        service.close()
        svc_session.close()
        router.close()


def test_tls_with_login_and_acl(tmp_path: Path, certs: Path) -> None:
    """docs/security/router.json5 and its clients with their TLS lines uncommented: a guest over
    TLS asks but cannot move; the operator moves."""
    tls_port, tcp_port = free_port(), free_port()
    users = str(DOCS / "users.txt")
    ca_commented = '// link: { tls: { root_ca_certificate: "ca.pem" } },'
    uncomment = {
        ca_commented: f'link: {{ tls: {{ root_ca_certificate: "{certs}/ca.pem" }} }},',
        f'"tcp/127.0.0.1:{tcp_port}"': f'"tls/127.0.0.1:{tls_port}"',
    }
    router_commented = '// tls: { listen_certificate: "router.pem", listen_private_key: "router.key" },'
    router_tls = f'tls: {{ listen_certificate: "{certs}/router.pem", listen_private_key: "{certs}/router.key" }},'

    router_conf = _copy(
        "router.json5",
        tmp_path,
        tcp_port,
        **{
            "docs/security/users.txt": users,
            router_commented: router_tls,
            f'endpoints: ["tcp/127.0.0.1:{tcp_port}"]': f'endpoints: ["tls/127.0.0.1:{tls_port}"]',
        },
    )
    router = zenoh.open(zenoh.Config.from_file(str(router_conf)))
    confs = {}
    for who in ("service", "adapter-gupta3", "operator", "guest"):
        path = _copy(f"{who}.json5", tmp_path, tcp_port)
        text = path.read_text()
        for old, new in uncomment.items():
            assert old in text, (who, old)
            text = text.replace(old, new)
        path.write_text(text)
        confs[who] = path
    arm = robots.load("gupta3")
    svc_session = zenoh.open(network_config(config_file=str(confs["service"])))
    service = Service(svc_session, {"gupta3": arm})
    adapter_session = zenoh.open(network_config(config_file=str(confs["adapter-gupta3"])))
    sim = SimAdapter(adapter_session, arm, time_scale=5.0)
    guest = ArmClient(config=str(confs["guest"]), timeout=2.0)
    operator = ArmClient(config=str(confs["operator"]), timeout=5.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")  # type: ignore[attr-defined]
        assert guest.fk("gupta3", [0.0, 1.0, -1.0]).within_limits
        with pytest.raises(NoReply):
            guest.move("gupta3", [0.5, 1.2, -1.0])
        operator.move("gupta3", [0.5, 1.2, -1.0], wait=True, wait_timeout=10)
        assert np.allclose(sim.position, [0.5, 1.2, -1.0], atol=1e-9)
    finally:
        guest.close()
        operator.close()
        sim.close()
        adapter_session.close()
        service.close()
        svc_session.close()
        router.close()


def test_the_router_drops_what_is_over_its_readers_size(secured: dict[str, Path]) -> None:
    """router.json5's low-pass filter: a guest's request over the service's 1 MB is dropped at
    the router (the service never copies it); one within it is answered."""
    arm = robots.load("gupta3")
    svc_session = zenoh.open(network_config(config_file=str(secured["service"])))
    service = Service(svc_session, {"gupta3": arm})
    guest = ArmClient(config=str(secured["guest"]), timeout=2.0)
    try:
        assert guest.ik("gupta3", arm.fk(np.array([0.2, 1.0, -1.1])).tolist()).status == "ok"
        wait_for(lambda: service.stats()["served"] == 1, what="the request counted")
        before = service.stats()["served"]
        replies = list(guest.session.get("armd/gupta3/ik", payload=b" " * 1_500_000, timeout=2.0))
        said = [(r.ok if r.ok is not None else r.err).payload.to_bytes() for r in replies]  # type: ignore[union-attr]
        assert said in ([], [b"Timeout"]) and service.stats()["served"] == before, said
    finally:
        guest.close()
        service.close()
        svc_session.close()
