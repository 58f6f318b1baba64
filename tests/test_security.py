"""docs/security: a router that authenticates every session and lets only trusted users move
arms. A guest's move is refused and nothing moves; an operator's works."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

import robots
from clients import ArmClient, NoReply
from clients.sim import SimAdapter
from service.server import Service
from service.zconfig import network_config
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
    confs = {who: _copy(f"{who}.json5", tmp_path, port) for who in ("service", "adapter", "operator", "guest")}
    confs["intruder"] = _copy("guest.json5", tmp_path, port, "intruder.json5",
                              **{'password: "guest"': 'password: "wrong"'})
    yield confs
    router.close()


def test_only_trusted_users_move_arms(secured: dict[str, Path]) -> None:
    arm = robots.load("gupta3")
    svc_session = zenoh.open(network_config(config_file=str(secured["service"])))
    service = Service(svc_session, {"gupta3": arm})
    adapter_session = zenoh.open(network_config(config_file=str(secured["adapter"])))
    sim = SimAdapter(adapter_session, arm, time_scale=5.0)
    guest = ArmClient(config=str(secured["guest"]), timeout=2.0)
    operator = ArmClient(config=str(secured["operator"]), timeout=5.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")  # type: ignore[attr-defined]
        start = sim.position.copy()
        # read-only verbs are open to a guest
        assert guest.ik("gupta3", arm.fk(np.array([0.2, 1.0, -1.1])).tolist()).status == "ok"
        assert [r["name"] for r in guest.robots()] == ["gupta3"]
        # a guest's move is refused: the router drops it, the service never sees it
        with pytest.raises(NoReply):
            guest.move("gupta3", [0.5, 1.2, -1.0])
        with pytest.raises(NoReply):
            guest.stop("gupta3")
        # and a guest cannot publish a trajectory to the adapter either
        traj = operator.plan("gupta3", [0.5, 1.2, -1.0], start=start)
        guest.session.put("armd/gupta3/trajectory", b'{"robot": "gupta3", "id": "x", "rate_hz": 50, "times": [0.0],'
                          b' "position": [[0.5, 1.2, -1.0]], "velocity": [[0, 0, 0]], "acceleration": [[0, 0, 0]]}')
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
