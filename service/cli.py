"""The ``armd`` command line.

``armd catalogue`` prints the arms armd knows (the built-in catalogue, plus a user's
``--robots-dir``), offline, with their joints and limits.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence

import robots
from robots import ArmdError, Robot


def _all_robots(robots_dir: str | None) -> dict[str, Robot]:
    arms = {name: robots.load(name) for name in robots.names()}
    if robots_dir:
        arms.update(robots.load_dir(robots_dir))
    return arms


def _deg(x: float) -> str:
    return f"{math.degrees(x):7.1f}"


def cmd_catalogue(args: argparse.Namespace) -> int:
    arms = _all_robots(args.robots_dir)
    if args.json:
        print(json.dumps({name: arm.describe() for name, arm in arms.items()}, indent=2))
        return 0
    for name, arm in arms.items():
        reach = arm.fk(arm.neutral)
        print(f"{name}: {arm.title}")
        print(f"  neutral tool point [m]: ({reach[0]:.4f}, {reach[1]:.4f}, {reach[2]:.4f})")
        print(f"  {'joint':<12} {'lower':>7} {'upper':>7}  deg   {'vmax':>6} {'amax':>6} {'jmax':>6}  (rad/s^k)")
        lim = arm.limits
        for i, j in enumerate(arm.joint_names):
            print(f"  {j:<12} {_deg(lim.lower[i])} {_deg(lim.upper[i])}      "
                  f"{lim.velocity[i]:6.2f} {lim.acceleration[i]:6.1f} {lim.jerk[i]:6.1f}")
        for c in lim.coupled:
            terms = " + ".join(f"{k:g}*{arm.joint_names[i]}" for i, k in enumerate(c.coefficients) if k)
            print(f"  coupled {c.name}: {c.lower:g} <= {terms} <= {c.upper:g} rad")
        acts = ", ".join(f"{a.name} ({a.kind})" for a in arm.actuators.actuators)
        print(f"  actuators: {acts}")
        if arm.sensors:
            print(f"  sensors: {', '.join(sorted(arm.sensors))}")
        print()
    return 0


def _numbers(values: list[str], what: str) -> list[float]:
    try:
        return [float(v) for v in values]
    except ValueError:
        raise robots.BadRequest(f"{what} must be numbers, got {' '.join(values)}", field=what) from None


def _approach(value: str | None) -> object:
    if value is None or value in ("parallel", "perpendicular", "free"):
        return value
    try:
        return float(value)
    except ValueError:
        raise robots.BadRequest(f"approach must be parallel, perpendicular, free or a pitch [rad], got {value!r}",
                                field="approach") from None


def cmd_plot(args: argparse.Namespace) -> int:
    import planning
    from planning.plot import plot_trajectory

    arms = _all_robots(args.robots_dir)
    if args.robot not in arms:
        raise robots.UnknownRobot(args.robot, arms)
    arm = arms[args.robot]
    start = _numbers(args.start, "start") if args.start else arm.neutral
    if (args.goal is None) == (args.target is None):
        raise robots.BadRequest("give exactly one of --goal Q... (joints) or --target X Y Z", field="goal")
    goal: object = (_numbers(args.goal, "goal") if args.goal is not None
                    else {"target": _numbers(args.target, "target"), "approach": _approach(args.approach)})
    traj = planning.plan(arm, start, goal, path=args.path, speed=args.speed, rate_hz=args.rate)
    out = plot_trajectory(traj, arm, args.out)
    print(f"{out}: {traj.path} trajectory of {arm.name}, {traj.duration:.3f} s, {len(traj.times)} samples "
          f"at {traj.rate_hz:g} Hz")
    return 0


def _network_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on (default tcp/127.0.0.1:7447 for the embedded router)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="join an existing Zenoh network through this endpoint instead of embedding a router")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5)")
    p.add_argument("--prefix", default="armd", help="key expression prefix (default armd)")


def _wait_for_signal() -> None:
    import signal
    import threading

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    while not stop.is_set():
        stop.wait(0.5)


def cmd_serve(args: argparse.Namespace) -> int:
    import logging

    import zenoh

    from service.server import Service
    from service.zconfig import network_config

    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    arms = _all_robots(args.robots_dir)
    conf = network_config(listen=args.listen, connect=args.connect, config_file=args.config)
    zenoh.init_log_from_env_or("error")
    session = zenoh.open(conf)
    service = Service(session, arms, prefix=args.prefix)
    sims = []
    if args.sim:
        from clients.sim import SimAdapter

        sims = [SimAdapter(session, arm, prefix=args.prefix, time_scale=args.time_scale) for arm in arms.values()]
    where = ", ".join(args.connect) if args.connect else ", ".join(args.listen or ["tcp/127.0.0.1:7447"])
    extra = f", with simulated arms (x{args.time_scale:g} real time)" if args.sim else ""
    print(f"armd serving {', '.join(arms)} on {where} (prefix {args.prefix}){extra}; Ctrl-C to stop", flush=True)
    try:
        _wait_for_signal()
    finally:
        for sim in sims:
            sim.close()
        service.close()
        session.close()
    return 0


def cmd_adapter(args: argparse.Namespace) -> int:
    import logging

    import zenoh

    from service.zconfig import network_config

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    arms = _all_robots(args.robots_dir)
    if args.robot not in arms:
        raise robots.UnknownRobot(args.robot, arms)
    connect = args.connect or ([] if args.listen or args.config else ["tcp/127.0.0.1:7447"])
    zenoh.init_log_from_env_or("error")
    session = zenoh.open(network_config(listen=args.listen, connect=connect or None, config_file=args.config))
    if args.kind == "sim":
        from clients.sim import SimAdapter

        adapter = SimAdapter(session, arms[args.robot], prefix=args.prefix, time_scale=args.time_scale)
    else:
        raise robots.BadRequest(f"adapter kind {args.kind!r} is not available yet; kinds: sim", field="kind")
    print(f"armd {args.kind} adapter {adapter.id} driving {args.robot}; Ctrl-C to stop", flush=True)
    try:
        _wait_for_signal()
    finally:
        adapter.close()
        session.close()
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    import zenoh

    from service.zconfig import network_config

    zenoh.init_log_from_env_or("error")
    session = zenoh.open(network_config(listen=args.listen or ["tcp/127.0.0.1:7447"], connect=args.connect,
                                        config_file=args.config, mode="router"))
    print(f"zenoh router {session.zid()} listening on {', '.join(args.listen or ['tcp/127.0.0.1:7447'])}",
          flush=True)
    try:
        _wait_for_signal()
    finally:
        session.close()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="armd", description="IK and motion service for small robot arms")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("catalogue", help="print the arms armd knows, offline")
    p.add_argument("--robots-dir", help="a folder of your own arms (robot.urdf + robot.toml each)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.set_defaults(func=cmd_catalogue)

    p = sub.add_parser("plot", help="plan a trajectory offline and write a PNG of it (limits drawn)")
    p.add_argument("robot")
    p.add_argument("--start", nargs="+", metavar="Q", help="start joint vector [rad] (default: neutral)")
    p.add_argument("--goal", nargs="+", metavar="Q", help="goal joint vector [rad]")
    p.add_argument("--target", nargs=3, metavar=("X", "Y", "Z"), help="goal tool point [m] in base")
    p.add_argument("--approach", help="parallel, perpendicular, free or a pitch [rad] (with --target)")
    p.add_argument("--path", choices=["joint", "line"], default="joint")
    p.add_argument("--speed", type=float, default=1.0, help="fraction of the velocity limits, (0, 1]")
    p.add_argument("--rate", type=float, default=None, help="samples per second (default: the arm's)")
    p.add_argument("--out", default="trajectory.png", help="PNG file to write")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("serve", help="run the service (embeds a Zenoh router unless --connect is given)")
    _network_args(p)
    p.add_argument("--robots-dir", help="a folder of your own arms, served with the catalogue")
    p.add_argument("-v", "--verbose", action="store_true", help="log one line per request")
    p.add_argument("--sim", action="store_true", help="also run a simulated arm (adapter) for every arm")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated time per real second (with --sim)")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("adapter", help="run a hardware adapter daemon for one arm")
    p.add_argument("kind", choices=["sim"], help="sim: a simulated arm")
    p.add_argument("robot")
    _network_args(p)
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated time per real second (sim)")
    p.set_defaults(func=cmd_adapter)

    p = sub.add_parser("router", help="run a standalone Zenoh router (no zenohd needed)")
    _network_args(p)
    p.set_defaults(func=cmd_router)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except ArmdError as e:
        print(f"armd: error: {e.message}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `armd catalogue | head`: the reader left; stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
