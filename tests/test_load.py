"""A short run of bench/load.py against a real service: every request answered exactly once
(none lost), no bad request answered ok and nothing answered ``internal``, and stops sent
during the load answered and honoured (the arm comes to rest short of its goal). Speed is
measured by the benchmark itself (docs/benchmarks.md), never asserted here."""

from __future__ import annotations

import pytest

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.service.server import Service
from bench.load import STOP_ARM, run
from tests.conftest import wait_for

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)


def test_load_with_a_stop_in_it(router: str, service: Service, adapter_session: object) -> None:
    arm = robots.load(STOP_ARM)
    sim = SimAdapter(adapter_session, arm)  # type: ignore[arg-type]
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the simulated arm")
        r = run(router, clients=2, threads=2, seconds=4.0, idle_stops=1)
    finally:
        sim.close()
    summary = {k: (v["lost"], v["wrong"], v["codes"]) for k, v in r["verbs"].items()}
    assert r["lost"] == 0 and r["wrong"] == 0, f"(lost, wrong, error codes) per verb: {summary}; {r['lost_detail']}"
    verbs = r["verbs"]
    assert {"ik", "fk", "plan", "batch", "bad"} <= set(verbs)
    assert all(v["ok"] == 0 for k, v in verbs.items() if k == "bad")
    assert not r["stop_failures"], r["stop_failures"]
    assert len(r["stop_load_ms"]) >= 1 and r["stops_honoured"]["load"] == len(r["stop_load_ms"])
    wait_for(lambda: service.stats()["in_flight"] == 0, what="an idle service")
