"""docs/protocol.md: every example request works as it is, and every JSON block parses."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
import zenoh

import robots
from clients import ArmClient
from clients.sim import SimAdapter

DOC = (Path(__file__).resolve().parent.parent / "docs" / "protocol.md").read_text()
EXAMPLES = re.findall(r"```json request (\S+)\n(.*?)```", DOC, flags=re.S)
BLOCKS = re.findall(r"```json\n(.*?)```", DOC, flags=re.S)


def test_the_doc_has_an_example_per_verb() -> None:
    verbs = {key.split("/")[-1] for key, _ in EXAMPLES}
    assert verbs >= {"robots", "info", "fk", "ik", "plan", "move", "stop"}


@pytest.mark.parametrize("block", BLOCKS)
def test_json_blocks_parse(block: str) -> None:
    json.loads(block)


def test_examples_work(router: str, service: object, client: ArmClient) -> None:
    from service.zconfig import network_config

    session = zenoh.open(network_config(connect=[router]))
    sims = [SimAdapter(session, robots.load(n), time_scale=20.0) for n in robots.names()]
    try:
        deadline = time.monotonic() + 5
        while min(service._adapter_count(robots.load(n)) for n in robots.names()) == 0:  # type: ignore[attr-defined]
            assert time.monotonic() < deadline
            time.sleep(0.05)
        for key, body in EXAMPLES:
            replies = list(client.session.get(key, payload=body.encode(), timeout=10.0))
            assert len(replies) == 1
            assert replies[0].ok is not None, (key, replies[0].err.payload.to_bytes())  # type: ignore[union-attr]
    finally:
        for s in sims:
            s.close()
        session.close()
