"""The commands that ask a running service (or its adapters) through the typed client
(:class:`armd.clients.ArmClient`): ``robots``, ``ik``, ``fk``, ``plan``, ``move``, ``stop``,
``estop`` and ``unlock``. ``--json`` prints the reply as the service sent it."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import numpy as np

from armd.clients import ArmClient
from armd.errors import BadRequest

from . import estop
from .common import approach, goal, motion_args, numbers


def _client(args: argparse.Namespace) -> ArmClient:
    return ArmClient(args.connect, config=args.config, prefix=args.prefix, timeout=args.timeout)


def _show(args: argparse.Namespace, reply: dict[str, Any], table: list[tuple[str, object]]) -> None:
    if args.json:
        print(json.dumps(reply, indent=2))
        return
    width = max(len(k) for k, _ in table)
    for k, v in table:
        if hasattr(v, "tolist"):
            v = v.tolist()
        if isinstance(v, float):
            v = f"{v:.6g}"
        elif isinstance(v, list) and v and all(isinstance(x, float) for x in v):
            v = "[" + ", ".join(f"{x:.4f}" for x in v) + "]"
        print(f"{k:<{width}}  {v}")


def cmd_robots(args: argparse.Namespace) -> int:
    with _client(args) as c:
        reply = {"robots": c.robots()}
    if args.json:
        print(json.dumps(reply, indent=2))
    else:
        for r in reply["robots"]:
            print(f"{r['name']:<12} {r['title']}  ({', '.join(r['joints'])})")
    return 0


def cmd_ik(args: argparse.Namespace) -> int:
    target = _ik_target(args)
    seed = numbers(args.seed, "seed") if args.seed else None
    with _client(args) as c:
        r = c.ik(args.robot, target, approach=approach(args.approach), seed=seed, roll=args.roll)
    _show(
        args,
        r.raw,
        [
            ("status", r.status),
            ("target [m]", np.array(r.raw["target"])),
            ("q [rad]", r.q),
            ("position error [m]", r.position_error),
            ("reached [m]", r.reached),
            ("pitch [rad]", r.pitch),
            ("roll [rad]", "" if r.roll is None else r.roll),
            ("branch", r.branch),
            ("other branches", len(r.branches)),
            ("in contact", "" if r.contact is None else f"{r.contact[0]} and {r.contact[1]}"),
            ("reason", r.reason or ""),
        ],
    )
    return 0 if r.ok else 1


def _ik_target(args: argparse.Namespace) -> object:
    """``X Y Z`` [m], or ``--sensor NAME RANGE [BEARING]``: exactly one."""
    if args.sensor is None:
        if len(args.xyz) != 3:
            raise BadRequest("ik needs a target: X Y Z [m], or --sensor NAME RANGE [BEARING]", field="target")
        return numbers(args.xyz, "target")
    if args.xyz:
        raise BadRequest("a target X Y Z or --sensor, not both", field="target")
    if not 2 <= len(args.sensor) <= 3:
        raise BadRequest("--sensor takes NAME RANGE [BEARING] (range [m], bearing [rad])", field="sensor")
    values = numbers(args.sensor[1:], "sensor")
    return {"sensor": args.sensor[0], "range": values[0], "bearing": values[1] if len(values) > 1 else 0.0}


def cmd_sequence(args: argparse.Namespace) -> int:
    target = _ik_target(args)
    with _client(args) as c:
        call = c.pick if args.command == "pick" else c.place
        r = call(
            args.robot,
            target,
            approach=args.approach,
            above=args.above,
            lift=args.lift,
            speed=args.speed,
            timeout=120.0,
        )
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        x, y, z = r["target"]
        print(f"{args.command} at [{x:.3f}, {y:.3f}, {z:.3f}] m, approach {r['approach']}:")
        for s in r["steps"]:
            what = (
                f"gripper {s['opening']:g}"
                if "opening" in s
                else f"{s['path']} to {s['target']}, {s['duration']:.2f} s"
            )
            mark = "done" if s["done"] else ("STOPPED" if s["step"] == r["stopped_at"] else "not done")
            print(f"  {s['step']}: {what}: {mark}")
        if not r["done"]:
            print(f"stopped at {r['stopped_at']}: {r['reason']}")
    return 0 if r["done"] else 1


def cmd_detect(args: argparse.Namespace) -> int:
    with _client(args) as c:
        r = c.detect(args.robot, sweeps=args.sweeps, sensors=args.sensor, wait=args.wait)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    objects = r["objects"]
    print(f"{len(objects)} object(s) seen by {', '.join(r['sensors'])} over {r['sweeps']} sweep(s)")
    for o in objects:
        x, y, z = o["position"]
        stable = "stable" if o["stable"] else "not stable"
        print(
            f"  at [{x:.3f}, {y:.3f}, {z:.3f}] m (+- {o['uncertainty'] * 1000:.0f} mm), "
            f"{o['width'] * 1000:.0f} mm wide, by {', '.join(o['sensors'])}: {stable} (seen {o['seen']}/{o['sweeps']})"
        )
    return 0


def cmd_gripper(args: argparse.Namespace) -> int:
    word = args.opening.lower()
    opening = {"open": 1.0, "close": 0.0, "closed": 0.0}.get(word)
    if opening is None:
        opening = numbers([args.opening], "opening")[0]
    with _client(args) as c:
        r = c.gripper(args.robot, opening)
    _show(args, r, [("opening", r["opening"]), ("command", r["pulse"]), ("id", r["id"])])
    return 0


def cmd_fk(args: argparse.Namespace) -> int:
    with _client(args) as c:
        r = c.fk(args.robot, numbers(args.q, "q"))
    _show(args, r.raw, [("position [m]", r.position), ("pitch [rad]", r.pitch), ("within limits", r.within_limits)])
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    start = numbers(args.start, "start") if args.start else None
    with _client(args) as c:
        t = c.plan(args.robot, goal(args), start=start, path=args.path, speed=args.speed)
        if args.plot:
            from armd.tools.plot import plot_reply  # (matplotlib: the view extra; main() says so)

            plot_reply(c, args.robot, t, args.plot)
    _show(
        args,
        t.raw,
        [
            ("path", t.path),
            ("duration [s]", t.duration),
            ("samples", len(t.times)),
            ("rate [Hz]", t.rate_hz),
            ("end [rad]", t.position[-1]),
            ("end commands", t.commands[-1]),
        ]
        + ([("plot", args.plot)] if args.plot else []),
    )
    return 0


def cmd_move(args: argparse.Namespace) -> int:
    with _client(args) as c:
        r = c.move(args.robot, goal(args), path=args.path, speed=args.speed)
        if args.wait:
            c.wait_until_still(args.robot, r.goal, timeout=r.duration + 10.0)
    _show(
        args,
        r.raw,
        [
            ("trajectory", r.id),
            ("path", r.path),
            ("duration [s]", r.duration),
            ("goal [rad]", r.goal),
            ("planned from", r.start_source),
        ],
    )
    return 0


def cmd_stop(args: argparse.Namespace) -> int:
    with _client(args) as c:
        r = c.stop(args.robot)
    _show(
        args,
        r,
        [
            ("trajectory", r["id"]),
            ("stops in [s]", r["duration"]),
            ("rest [rad]", r["rest"]),
            ("adapters", r["adapters"]),
        ],
    )
    return 0


def cmd_unlock(args: argparse.Namespace) -> int:
    """An operator's word to an adapter that lost the arm's position (GRBL after a reset or an alarm)."""
    how = "home" if args.home else "assume_rest"
    with _client(args) as c:
        answer = c.unlock(args.robot, how, wait=args.wait)
    if answer is None:
        print(f"armd: no adapter of {args.robot} answered the unlock within {args.wait} s", file=sys.stderr)
        return 1
    if answer["event"] != "unlocked":
        print(f"armd: error: {answer.get('reason', answer)}", file=sys.stderr)
        return 1
    print(f"{args.robot}: unlocked ({how})")
    return 0


def cmd_world(args: argparse.Namespace) -> int:
    """List, add to or remove from an arm's world (its obstacles) on the service."""
    add = []
    for kind, specs in (("box", args.box), ("sphere", args.sphere), ("cylinder", args.cylinder)):
        n = {"box": 3, "sphere": 1, "cylinder": 2}[kind]
        for spec in specs or ():
            name, *numbers = spec
            try:
                values = [float(x) for x in numbers]
            except ValueError:
                print(f"armd: error: --{kind} {' '.join(spec)}: NAME then {len(numbers)} numbers [m]", file=sys.stderr)
                return 2
            add.append({"name": name, "shape": kind, "position": values[:3], "size": values[3 : 3 + n]})
    with _client(args) as c:
        r = c.world(args.robot, add=add, remove=args.remove or (), clear=args.clear)
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    world = r["world"]
    if world is None:
        print(f"{args.robot}: no collision model (no world)")
        return 0
    ground = world["ground"]
    print(f"{args.robot}: ground {'none' if ground is None else f'z = {ground:g} m'}")
    fixed = set(r["fixed"])
    for o in world["obstacles"]:
        where = ", ".join(f"{x:g}" for x in o["position"])
        size = ", ".join(f"{x:g}" for x in o["size"])
        turned = "" if not any(o["rpy"]) else f", rpy [{', '.join(f'{x:g}' for x in o['rpy'])}]"
        kept = " (robot.toml)" if o["name"] in fixed else ""
        print(f"  {o['name']}: {o['shape']} [{size}] m at [{where}] m{turned}{kept}")
    for a, b in r["contacts"]:
        print(f"  in contact now: {a} and {b} (plans from here are refused)")
    return 0


def _client_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="default tcp/127.0.0.1:7447")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5)")
    p.add_argument("--prefix", default="armd")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the service")
    p.add_argument("--json", action="store_true", help="print the reply as JSON")


def register(sub: Any, log_args: argparse.ArgumentParser) -> None:
    p = sub.add_parser("robots", parents=[log_args], help="the arms a running service serves")
    _client_args(p)
    p.set_defaults(func=cmd_robots)

    p = sub.add_parser("ik", parents=[log_args], help="inverse kinematics from the service: armd ik ROBOT X Y Z")
    p.add_argument("robot")
    p.add_argument("xyz", nargs="*", metavar="X/Y/Z", help="target [m] in the arm's base frame (or --sensor)")
    p.add_argument(
        "--sensor",
        nargs="+",
        metavar="NAME RANGE [BEARING]",
        help="a range sensor's reading as the target: its name, range [m] and bearing [rad] (a sensor on the "
        "arm is read where the arm is: --seed, else its adapter's state)",
    )
    p.add_argument("--approach", help="parallel, perpendicular, free or a pitch [rad]")
    p.add_argument("--roll", type=float, help="the tool's roll about its axis [rad] (an arm with a wrist roll)")
    p.add_argument("--seed", nargs="+", metavar="Q", help="current joint vector [rad]")
    _client_args(p)
    p.set_defaults(func=cmd_ik)

    p = sub.add_parser("fk", parents=[log_args], help="forward kinematics from the service: armd fk ROBOT Q...")
    p.add_argument("robot")
    p.add_argument("q", nargs="+", help="joint vector [rad]")
    _client_args(p)
    p.set_defaults(func=cmd_fk)

    p = sub.add_parser("plan", parents=[log_args], help="plan a trajectory on the service (nothing moves)")
    motion_args(p)
    p.add_argument("--start", nargs="+", metavar="Q", help="start joint vector (default: where the arm is)")
    p.add_argument("--plot", metavar="FILE.png", help="also write a PNG of the trajectory (limits drawn)")
    _client_args(p)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("move", parents=[log_args], help="move an arm (needs an adapter: hardware or --sim)")
    motion_args(p)
    p.add_argument("--wait", action="store_true", help="return when the arm is at rest at the goal")
    _client_args(p)
    p.set_defaults(func=cmd_move)

    for verb, what in (("pick", "open, above, descend, close, lift"), ("place", "above, descend, open, rise")):
        p = sub.add_parser(verb, parents=[log_args], help=f"{verb} an object at X Y Z (or --sensor): {what}")
        p.add_argument("robot")
        p.add_argument("xyz", nargs="*", metavar="X/Y/Z", help="the object's centre where it is held [m], base frame")
        p.add_argument("--sensor", nargs="+", metavar="NAME RANGE [BEARING]", help="a range sensor's reading instead")
        p.add_argument("--approach", choices=["perpendicular", "parallel"], help="from above (default) or level")
        p.add_argument("--above", type=float, help="the pre-grasp pose's distance from it [m] (default 0.06)")
        p.add_argument("--lift", type=float, help="how far to lift (pick) or rise (place) [m] (default 0.06)")
        p.add_argument("--speed", type=float, help="fraction of the limits (default 0.5)")
        _client_args(p)
        p.set_defaults(func=cmd_sequence)

    p = sub.add_parser("detect", parents=[log_args], help="the objects an arm's scanning range sensors see")
    p.add_argument("robot")
    p.add_argument("--sweeps", type=int, default=None, help="how many last sweeps must show an object (default 2)")
    p.add_argument("--sensor", action="append", help="a scanner to look with (default: every scanner)")
    p.add_argument(
        "--wait",
        type=float,
        default=30.0,
        help="[s] ask again while the scanners have not swept enough (default 30: a real sweep takes seconds)",
    )
    _client_args(p)
    p.set_defaults(func=cmd_detect)

    p = sub.add_parser("gripper", parents=[log_args], help="open or close an arm's gripper: open, close or 0..1")
    p.add_argument("robot")
    p.add_argument("opening", help="open, close, or an opening from 0 (closed) to 1 (open)")
    _client_args(p)
    p.set_defaults(func=cmd_gripper)

    p = sub.add_parser("stop", parents=[log_args], help="stop an arm now")
    p.add_argument("robot")
    _client_args(p)
    p.set_defaults(func=cmd_stop)

    p = sub.add_parser(
        "world", parents=[log_args], help="an arm's obstacles on the service: list, --box/--sphere/--cylinder, --remove"
    )
    p.add_argument("robot")
    p.add_argument("--box", nargs=7, action="append", metavar=("NAME", "X", "Y", "Z", "SX", "SY", "SZ"))
    p.add_argument("--sphere", nargs=5, action="append", metavar=("NAME", "X", "Y", "Z", "R"))
    p.add_argument("--cylinder", nargs=6, action="append", metavar=("NAME", "X", "Y", "Z", "R", "L"))
    p.add_argument("--remove", action="append", metavar="NAME", help="an obstacle added before")
    p.add_argument("--clear", action="store_true", help="remove every obstacle added at run time")
    _client_args(p)
    p.set_defaults(func=cmd_world)

    p = sub.add_parser("estop", parents=[log_args], help=estop.HELP)  # (run by estop.main: this is its help)
    estop.add_arguments(p)
    p.set_defaults(func=estop.run)

    p = sub.add_parser(
        "unlock", parents=[log_args], help="tell an adapter that lost the arm's position where the arm is"
    )
    p.add_argument("robot")
    how = p.add_mutually_exclusive_group(required=True)
    how.add_argument("--home", action="store_true", help="run the controller's homing cycle ($H)")
    how.add_argument("--assume-rest", action="store_true", help="the arm is at its rest pose: I checked")
    p.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the adapter's answer")
    _client_args(p)
    p.set_defaults(func=cmd_unlock)
