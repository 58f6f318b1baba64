"""What moves the arm never waits behind a flood of IK batches (issue 14): with 80 batches of
10,000 targets in flight (bench/flood.py's flood, a process of its own), an operator's move and
stop are answered. The bounds are loose (the benchmark measures: docs/benchmarks.md); before
move had a pool of its own, it waited 3.6 s behind the batches."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.service.server import Service
from tests.conftest import wait_for

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent
MOVE_BOUND = 2.0  # [s] (bench/flood.py: tens of milliseconds)
STOP_BOUND = 1.0  # [s]


def test_move_and_stop_never_wait_behind_ik_batches(
    router: str, service: Service, client: ArmClient, adapter_session: object
) -> None:
    arm = robots.load("insomniac")
    sim = SimAdapter(adapter_session, arm)  # type: ignore[arg-type]
    flood = subprocess.Popen(
        [
            sys.executable,
            str(ROOT / "bench" / "flood.py"),
            "--worker",
            "flood",
            "--endpoint",
            router,
            "--batches",
            "80",
            "--targets",
            "10000",
            "--seconds",
            "12",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the simulated arm")
        assert flood.stdout is not None and flood.stdout.readline().strip() == "ready"
        wait_for(lambda: service.stats()["in_flight"] >= 40, timeout=20, what="the flood")
        for goal in ([1.2, 2.0, -1.8, 1.0, 1.0], [-0.9, 1.0, -0.6, -1.0, -1.0]):
            t = time.monotonic()
            client.move("insomniac", goal)
            moved = time.monotonic() - t
            time.sleep(0.3)
            t = time.monotonic()
            client.stop("insomniac")
            stopped = time.monotonic() - t
            assert service.stats()["in_flight"] >= 20, "the flood ran dry: the test measured nothing"
            assert moved <= MOVE_BOUND and stopped <= STOP_BOUND, (moved, stopped)
            time.sleep(0.5)
    finally:
        flood.kill()
        flood.wait()
        sim.close()
    wait_for(lambda: service.stats()["in_flight"] == 0, timeout=60, what="the batches drained")
