"""Junk on every key an adapter or the service listens on (issue 14): trajectories, gripper
commands, unlocks, estops, states, events, drawn by Hypothesis (valid messages broken in one
place, and arbitrary JSON and bytes), put straight on the keys through a real router. The
adapter keeps running and never moves the arm for any of it (an estop at rest stays at rest),
the service keeps its own picture of the arm and keeps serving."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.service.zconfig import network_config
from tests.conftest import wait_for

ARM = "desk4"
KEYS = ("trajectory", "gripper", "unlock", "estop", "state", "events")

_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
)
_json = st.recursive(
    _scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=12,
)


def _valid(arm: robots.Robot, key: str) -> dict[str, Any]:
    """A well-formed message of each key, for ``key`` (the fuzz breaks it in one place)."""
    q = list(arm.neutral)
    n = arm.nq
    return {
        "trajectory": {
            "robot": ARM,
            "id": "fuzz",
            "kind": "move",
            "rate_hz": 50.0,
            "times": [0.0, 0.02],
            "position": [q, q],
            "velocity": [[0.0] * n] * 2,
            "acceleration": [[0.0] * n] * 2,
        },
        "gripper": {"opening": 0.5, "id": "fuzz"},
        "unlock": {"how": "assume_rest"},
        "estop": {"id": "fuzz"},
        "state": {
            "robot": ARM,
            "adapter": "fuzzer",
            "seq": 1,
            "position": q,
            "velocity": [0.0] * n,
            "acceleration": [0.0] * n,
            "moving": False,
        },
        "events": {"event": "accepted", "id": "fuzz", "adapter": "fuzzer"},
    }[key]


@st.composite
def messages(draw: st.DrawFn, arm: robots.Robot) -> tuple[str, bytes]:
    key = draw(st.sampled_from(KEYS))
    how = draw(st.sampled_from(["broken", "json", "bytes"]))
    if how == "bytes":
        return key, draw(st.binary(max_size=64))
    if how == "json":
        return key, json.dumps(draw(_json), allow_nan=True).encode()
    msg = _valid(arm, key)
    field = draw(st.sampled_from([*msg, "extra"]))
    msg[field] = draw(_json)
    return key, json.dumps(msg, allow_nan=True).encode()


def test_junk_on_the_adapters_keys_moves_nothing(
    client: ArmClient, service: object, adapter_session: zenoh.Session, router: str
) -> None:
    arm = robots.load(ARM)
    sim = SimAdapter(adapter_session, arm)
    junk = zenoh.open(network_config(connect=[router]))  # (anyone on the network)
    try:
        wait_for(lambda: client.state(ARM)["source"] == "adapter", what="the adapter's state")
        start = sim.position.copy()

        @settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck))
        @given(messages(arm))
        def put(m: tuple[str, bytes]) -> None:
            junk.put(f"armd/{ARM}/{m[0]}", m[1])

        put()
        time.sleep(1.0)  # (what was put has arrived and been dealt with)
        assert sim._thread.is_alive()  # type: ignore[attr-defined]
        assert np.allclose(sim.position, start, atol=1e-12), "junk moved the arm"
        s = client.state(ARM)
        assert s["source"] == "adapter" and np.allclose(s["position"], start, atol=1e-9)
        # and both still work: a real move
        goal = (np.array(arm.neutral) + 0.1).tolist()
        client.move(ARM, goal, wait=True, wait_timeout=10)
        assert np.allclose(sim.position, goal, atol=1e-6)
    finally:
        junk.close()
        sim.close()
