"""The ``world`` verb: an arm's obstacles added, listed and removed at run time over Zenoh,
validated like every request, seen by the next IK and plan; the CLI's ``armd world``."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_plan_clearance import swing

from armd import robots
from armd.clients import ArmClient
from armd.errors import BadRequest, CollisionError

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def armd(client: ArmClient) -> Iterator[ArmClient]:
    """The shared test service's client; every obstacle added is removed again afterwards."""
    yield client
    for name in robots.names():
        client.world(name, clear=True)


def _crate(arm: robots.Robot, name: str = "crate", size: float = 0.06) -> dict[str, object]:
    """A box on the tool point of ``arm``'s neutral pose (on the tool's arc when the yaw turns)."""
    tip = arm.fk(arm.neutral)
    return {"name": name, "shape": "box", "size": [size] * 3, "position": [float(tip[0]), 0.0, float(tip[2])]}


def test_obstacles_added_listed_seen_and_removed(armd: ArmClient) -> None:
    arm = robots.load("insomniac")
    empty = armd.world("insomniac")
    assert empty["world"]["obstacles"] == [] and empty["world"]["ground"] == 0.0 and empty["contacts"] == []
    start, goal = swing(arm, 0.8)
    straight = armd.plan("insomniac", list(goal), start=list(start))
    r = armd.world(
        "insomniac",
        add=[_crate(arm), {"name": "ball", "shape": "sphere", "size": [0.03], "position": [-0.2, 0.2, 0.1]}],
    )
    names = [o["name"] for o in r["world"]["obstacles"]]
    assert names == ["crate", "ball"] and r["fixed"] == []
    assert ["gripper", "crate"] in r["contacts"]  # (the arm stands at neutral: its tool is in the crate)
    assert armd.info("insomniac")["world"]["obstacles"] == r["world"]["obstacles"]
    # the next requests see it: IK into the crate is a collision, the joint move goes round it
    under = armd.ik("insomniac", list(arm.fk(arm.neutral)))
    assert under.status == "collision" and under.contact is not None and "crate" in under.contact
    around = armd.plan("insomniac", list(goal), start=list(start))
    assert around.duration > straight.duration
    with pytest.raises(CollisionError) as e:
        armd.plan("insomniac", {"target": list(arm.fk(arm.neutral))}, start=list(start), path="line")  # into it
    assert "crate" in e.value.pair
    # removed: the straight move again
    r = armd.world("insomniac", remove=["crate"])
    assert [o["name"] for o in r["world"]["obstacles"]] == ["ball"] and r["contacts"] == []
    assert armd.plan("insomniac", list(goal), start=list(start)).duration == pytest.approx(straight.duration)
    assert armd.world("insomniac", clear=True)["world"]["obstacles"] == []
    assert robots.load("insomniac").collision.obstacles == ()  # type: ignore[union-attr]  # (the service's own copy)


BAD = [
    ({"add": [{"name": "a", "shape": "cone", "size": [0.1], "position": [0, 0, 0]}]}, "add[0].shape"),
    ({"add": [{"name": "a", "shape": "box", "size": [0.1, 0.1], "position": [0, 0, 0]}]}, "add[0].size"),
    ({"add": [{"name": "a", "shape": "box", "size": [0.1, 0.1, -1], "position": [0, 0, 0]}]}, "add[0].size[2]"),
    ({"add": [{"name": "a", "shape": "sphere", "size": [0.1], "position": [0, 0, 1e9]}]}, "add[0].position[2]"),
    ({"add": [{"name": "a", "shape": "sphere", "size": [0.1]}]}, "add[0].position"),
    ({"add": [{"name": "a", "shape": "sphere", "size": [0.1], "position": [0, 0, 0], "colour": 1}]}, "add[0].colour"),
    ({"add": [{"name": "ground", "shape": "sphere", "size": [0.1], "position": [0, 0, 1]}]}, "add[0].name"),
    ({"add": [{"name": "forearm", "shape": "sphere", "size": [0.1], "position": [0, 0, 1]}]}, "add[0].name"),
    (
        {"add": [{"name": "b", "shape": "sphere", "size": [0.1], "position": [0, 0, 1]}] * 2},
        "add[1].name",
    ),
    ({"add": []}, "add"),
    ({"remove": ["nothing-here"]}, "remove[0]"),
    ({"remove": "crate"}, "remove"),
    ({"clear": 1}, "clear"),
    ({"obstacles": []}, "obstacles"),
]


@pytest.mark.parametrize(("request_", "field"), BAD)
def test_bad_world_requests_change_nothing(armd: ArmClient, request_: dict[str, object], field: str) -> None:
    armd.world("insomniac", add=[{"name": "keep", "shape": "sphere", "size": [0.02], "position": [-0.3, -0.3, 0.1]}])
    before = armd.world("insomniac")
    with pytest.raises(BadRequest) as e:
        armd.call("insomniac/world", request_)
    assert e.value.code == "bad_request" and e.value.field == field, e.value.message
    assert armd.world("insomniac") == before  # all or nothing


def test_the_protocol_takes_the_shapes_the_checker_knows() -> None:
    from armd.robots.collision import SIZES
    from armd.service.protocol import SHAPES

    assert tuple(SIZES) == SHAPES


def test_at_most_64_obstacles_are_added(armd: ArmClient) -> None:
    many = [{"name": f"s{i}", "shape": "sphere", "size": [0.005], "position": [-0.4, 0.4, 0.01 * i]} for i in range(65)]
    with pytest.raises(BadRequest):
        armd.world("gupta3", add=many)
    assert len(armd.world("gupta3", add=many[:64])["world"]["obstacles"]) == 64


def test_the_cli_adds_lists_and_removes(armd: ArmClient, router: str) -> None:
    cli = [sys.executable, "-m", "armd.cli", "world", "gupta3", "--connect", router]
    out = subprocess.run(
        [
            *cli,
            "--box",
            "crate",
            "0.2",
            "0.1",
            "0.05",
            "0.04",
            "0.04",
            "0.04",
            "--sphere",
            "ball",
            "-0.2",
            "0",
            "0.1",
            "0.03",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert "crate: box [0.04, 0.04, 0.04] m at [0.2, 0.1, 0.05] m" in out.stdout
    assert "ball: sphere [0.03] m at [-0.2, 0, 0.1] m" in out.stdout and "gupta3: ground z = -0.12 m" in out.stdout
    assert [o["name"] for o in armd.world("gupta3")["world"]["obstacles"]] == ["crate", "ball"]
    out = subprocess.run([*cli, "--remove", "crate"], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0 and "crate" not in out.stdout and "ball" in out.stdout
    bad = subprocess.run(
        [*cli, "--sphere", "x", "1", "2", "three", "4"], capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    assert bad.returncode == 2 and "NAME then 4 numbers" in bad.stderr
    assert np.isclose(armd.world("gupta3")["world"]["obstacles"][0]["size"][0], 0.03)
