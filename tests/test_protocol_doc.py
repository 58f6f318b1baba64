"""docs/protocol.md: every example request works as it is, and every JSON block parses."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
import zenoh

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient

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
    from armd.service.zconfig import network_config

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


def test_the_schemas_name_the_fields_the_code_takes() -> None:
    """Each verb's JSON Schema in the doc has the top-level fields of the verb's shape in
    service/protocol.py, no more, no fewer (the envelope aside)."""
    from armd.service.protocol import ANY, FK, IK_BATCH, IK_ONE, PLAN

    shapes = {"q": FK, "target": IK_ONE, "targets": IK_BATCH, "goal": PLAN}
    seen = set()
    for block in BLOCKS:
        schema = json.loads(block)
        if schema.get("type") != "object" or not schema.get("required"):
            continue
        shape = shapes[schema["required"][0]]
        documented = set(schema["properties"]) - {"protocol", "deadline"}
        assert documented == {k for k, v in shape.fields.items() if v is not ANY}, schema["required"]
        assert schema["additionalProperties"] is False
        seen.add(schema["required"][0])
    assert seen == set(shapes)


def test_the_sizes_and_the_speed_floor_are_the_codes() -> None:
    from armd.planning.plan import MIN_SPEED
    from armd.service.protocol import MAX_METRES, MAX_RADIANS, MAX_RATE

    rows = dict(re.findall(r"^ *\| (a Cartesian coordinate|a joint value|a start state's)[^|]*\| (\S+) \|$", DOC, re.M))
    assert {k: float(v) for k, v in rows.items()} == {
        "a Cartesian coordinate": MAX_METRES,
        "a joint value": MAX_RADIANS,
        "a start state's": MAX_RATE,
    }
    speed = re.search(r'"speed": \{"type": "number", "minimum": ([0-9.e+-]+), "maximum": 1', DOC)
    assert speed is not None and float(speed.group(1)) == MIN_SPEED
