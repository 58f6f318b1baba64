"""What moves the arm never waits behind a flood of IK batches (issue 14): with 80 batches of
10,000 targets in flight from a guest (bench/flood.py's flood, a process of its own), an
operator's move and stop are answered. Through the secure setup (docs/security.md: a router
with logins and the ACL, each side its own user), as a deployment has it; the adapter a process
of its own. The bounds are looser than the benchmark's bars (0.3 s and 2 s; it measures ~0.1
and ~0.2 s: docs/benchmarks.md); before move had a pool of its own, it waited 3.6 s behind the
batches."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from armd import robots
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import wait_for
from tests.test_security import secured  # noqa: F401 (the fixture: a router with the ACL, and each role's config)

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent
MOVE_BOUND = 2.5  # [s] (the bar: 2 s; bench/flood.py: ~0.2 s; with move queued behind the batches: 3.6 s)
STOP_BOUND = 1.0  # [s] (the bar: 0.3 s; bench/flood.py: ~0.15 s)


def test_move_and_stop_never_wait_behind_a_guests_ik_batches(secured: dict[str, Path]) -> None:  # noqa: F811
    arm = robots.load("insomniac")
    session = zenoh.open(network_config(config_file=str(secured["service"])))
    service = Service(session, {"insomniac": arm, "desk4": robots.load("desk4")})
    cli = [sys.executable, "-m", "armd.cli"]
    adapter = subprocess.Popen(
        [*cli, "adapter", "sim", "insomniac", "--config", str(secured["adapter-insomniac"])],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    flood = subprocess.Popen(
        [
            sys.executable,
            str(ROOT / "bench" / "flood.py"),
            "--worker",
            "flood",
            "--config",
            str(secured["guest"]),
            "--batches",
            "80",
            "--targets",
            "10000",
            "--seconds",
            "15",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    operator = ArmClient(config=str(secured["operator"]), timeout=10.0)
    try:
        wait_for(lambda: operator.state("insomniac")["source"] == "adapter", timeout=60, what="the simulated arm")
        assert flood.stdout is not None and flood.stdout.readline().strip() == "ready"
        wait_for(lambda: service.stats()["in_flight"] >= 40, timeout=20, what="the guest's flood")
        for goal in ([1.2, 2.0, -1.8, 1.0, 1.0], [-0.9, 1.0, -0.6, -1.0, -1.0]):
            t = time.monotonic()
            r = operator.move("insomniac", goal)
            moved = time.monotonic() - t
            time.sleep(0.3)
            t = time.monotonic()
            operator.stop("insomniac")
            stopped = time.monotonic() - t
            assert service.stats()["in_flight"] >= 20, "the flood ran dry: the test measured nothing"
            assert r.adapter and moved <= MOVE_BOUND and stopped <= STOP_BOUND, (moved, stopped)
            time.sleep(0.5)
    finally:
        flood.kill()
        flood.wait()
        adapter.terminate()
        adapter.wait(10)
        operator.close()
    wait_for(lambda: service.stats()["in_flight"] == 0, timeout=60, what="the batches drained")
    service.close()
    session.close()
