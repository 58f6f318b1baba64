"""Seed 000's scenario in the simulator, as a client runs it: the Insomniac's scanning GP2D12s
find an object on the floor, the arm picks it up and puts it down on its left.

The steps are the service's verbs: ``detect`` until an object is stable (two sweeps, the seed's
test), ``pick`` at its place (from above, at ``GRASP_HEIGHT``: the seed's test objects are known
ones, taller than the beams), ``place`` a quarter turn to the arm's left about its base's axis,
at the same distance (no farther than ``PLACE_REACH``). ``armd demo`` runs it with a can on the
simulated insomniac's floor (``CAN``) and checks where the can ends up.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from armd.clients import ArmClient
from armd.errors import ArmdError

ROBOT = "insomniac"
CAN = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.28, -0.02]}
GRASP_HEIGHT = 0.06  # [m] where the gripper holds an object: below the beams (0.10 m), above the floor
PLACE_REACH = 0.26  # [m] the farthest from the base's axis it puts an object down
FIND_FOR = 10.0  # [s] how long it looks for a stable object


def run(client: ArmClient, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Find, pick, place: what each step answered (``found``, ``pick``, ``place``) and where the
    object was asked to go (``put_at``)."""
    found = None
    until = time.monotonic() + FIND_FOR
    while found is None:
        try:
            objects = client.detect(ROBOT, sweeps=2)["objects"]
            found = next((o for o in objects if o["stable"]), None)
        except ArmdError as e:
            if e.code != "not_ready":
                raise
        if found is None:
            if time.monotonic() > until:
                raise ArmdError(f"seed 000: no stable object seen in {FIND_FOR:g} s")
            time.sleep(0.2)
    x, y = found["position"][:2]
    say(f"seed 000: an object at [{x:.3f}, {y:.3f}] m, {found['width'] * 1000:.0f} mm wide, stable over 2 sweeps")
    pick = client.pick(ROBOT, [x, y, GRASP_HEIGHT])
    say(f"seed 000: pick {'done' if pick['done'] else 'stopped at ' + str(pick['stopped_at'])}")
    r = min(math.hypot(x, y), PLACE_REACH)
    angle = math.atan2(y, x) + math.pi / 2  # a quarter turn to its left
    put_at = [r * math.cos(angle), r * math.sin(angle)]
    place = client.place(ROBOT, [*put_at, GRASP_HEIGHT]) if pick["done"] else None
    if place is not None:
        say(f"seed 000: place at [{put_at[0]:.3f}, {put_at[1]:.3f}] m {'done' if place['done'] else 'stopped'}")
    return {"found": found, "pick": pick, "place": place, "put_at": put_at}
