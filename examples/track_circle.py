"""Draw a circle with the tool: stream its points at 100 Hz to armd's tracking stream.

Run `armd serve --sim` first, then: python examples/track_circle.py [ROBOT] [--connect tcp/HOST:7447]
"""

import argparse
import math
import time

from armd.clients import ArmClient

parser = argparse.ArgumentParser()
parser.add_argument("robot", nargs="?", default="insomniac")
parser.add_argument("--connect", default="tcp/127.0.0.1:7447")
parser.add_argument("--radius", type=float, default=0.05)  # [m]
parser.add_argument("--speed", type=float, default=0.2)  # [m/s] along the circle
args = parser.parse_args()

with ArmClient(args.connect) as armd, armd.track(args.robot) as track:
    x, y, z = armd.fk(args.robot, armd.info(args.robot)["state"]["position"]).position  # it starts where the tool is
    start = time.monotonic()
    for k in range(int(2 * math.pi * args.radius / args.speed * 100) + 1):  # one turn, a put every 10 ms
        angle = args.speed / args.radius * k / 100
        track.send(target=[x, y + args.radius * math.sin(angle), z - args.radius * (1 - math.cos(angle))])
        time.sleep(max(0.0, start + (k + 1) / 100 - time.monotonic()))
    print([f"{e.status}: {e.message}" for e in track.events])  # what it did not follow, and why
