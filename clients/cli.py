"""The ``armd`` command line: the top of the layers, wiring the service, the adapters and the client.

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
from typing import Any

from armd import robots
from armd.robots import ArmdError, Robot


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
    from armd import planning
    from armd.planning.plot import plot_trajectory

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
                   help="endpoint to listen on (default: the --config file's, else tcp/127.0.0.1:7447 for the "
                   "embedded router)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="join an existing Zenoh network through this endpoint instead of embedding a router")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5), used as it is: its endpoints, TLS, "
                   "credentials; --listen/--connect, where given, replace its endpoints")
    p.add_argument("--prefix", default="armd", help="key expression prefix (default armd)")


def _wait_for_signal() -> None:
    import signal
    import threading

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    while not stop.is_set():
        stop.wait(0.5)


def _open(conf: Any) -> Any:
    """A Zenoh session on ``conf``, after one warning line on stderr where it listens on the
    network with no authentication (:func:`service.zconfig.exposure_warning`); an endpoint
    Zenoh cannot open is an error naming it, not a traceback."""
    import zenoh

    from armd.service.zconfig import exposure_warning

    warning = exposure_warning(conf)
    if warning:
        print(f"armd: warning: {warning}", file=sys.stderr, flush=True)
    zenoh.init_log_from_env_or("error")
    try:
        return zenoh.open(conf)
    except zenoh.ZError as e:
        raise robots.BadRequest(f"Zenoh cannot open the session: {str(e).split(' at /')[0]}") from None


def _where(conf: Any) -> str:
    """Where a session on ``conf`` is: its connect endpoints, else its listen endpoints."""
    from armd.service.zconfig import endpoints

    return ", ".join(endpoints(conf, "connect") or endpoints(conf, "listen")) or "no endpoint"


def cmd_serve(args: argparse.Namespace) -> int:
    import logging

    from armd.service.protocol import Limits
    from armd.service.server import Service
    from armd.service.zconfig import network_config

    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    limits = Limits(max_payload_bytes=args.max_payload, max_batch=args.max_batch, max_depth=args.max_depth,
                    max_waypoints=args.max_waypoints, max_samples=args.max_samples, deadline=args.deadline)
    if args.workers < 1:
        raise robots.BadRequest(f"--workers must be >= 1, got {args.workers}", field="workers")
    arms = _all_robots(args.robots_dir)
    conf = network_config(listen=args.listen, connect=args.connect, config_file=args.config)
    stop = _signals()  # before the line that says it is up: a SIGTERM right after it stops it cleanly
    session = _open(conf)
    try:
        service = Service(session, arms, prefix=args.prefix, limits=limits, workers=args.workers)
    except BaseException:
        session.close()  # a Zenoh session left open would keep the process from exiting
        raise
    sims = []
    if args.sim:
        from armd.clients.sim import SimAdapter

        sims = [SimAdapter(session, arm, prefix=args.prefix, time_scale=args.time_scale) for arm in arms.values()]
    extra = f", with simulated arms (x{args.time_scale:g} real time)" if args.sim else ""
    print(f"armd serving {', '.join(arms)} on {_where(conf)} (prefix {args.prefix}){extra}; Ctrl-C to stop", flush=True)
    try:
        while not stop.is_set():
            stop.wait(0.5)
    finally:
        for sim in sims:
            sim.close()
        service.close()
        session.close()
    return 0


def cmd_adapter(args: argparse.Namespace) -> int:
    """The port first (a missing or busy one: one line naming it, exit 1), then Zenoh (retried
    until a router answers), then the adapter."""
    import logging

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    arms = _all_robots(args.robots_dir)
    if args.robot not in arms:
        raise robots.UnknownRobot(args.robot, arms)
    arm = arms[args.robot]
    port = None
    if args.kind != "sim":
        from armd.clients.adapter import ControllerFault
        from armd.clients.serial_port import open_port  # (pyserial: the hardware extra; main() says so)

        if not args.port:
            raise robots.BadRequest(f"the {args.kind} adapter needs --port (e.g. /dev/ttyUSB0)", field="port")
        baud = args.baud or int(arm.controller.get("baud", 115200))  # type: ignore[call-overload]
        try:
            port = open_port(args.port, baud, 0.5, 0.5, exclusive=True)
        except ControllerFault as e:
            print(f"armd: {e.message}", file=sys.stderr)
            return 1
    stop = _signals()
    session = _join(args, stop)
    if session is None:  # interrupted while waiting for a router
        if port is not None:
            port.close()
        return 0
    try:
        adapter = _make_adapter(args, session, arm, port)
    except robots.ArmdError as e:
        session.close()  # a Zenoh session left open would keep the process from exiting
        print(f"armd: {e.message}", file=sys.stderr)
        return 1
    except BaseException:
        session.close()
        raise
    print(f"armd {args.kind} adapter {adapter.id} driving {args.robot}; Ctrl-C to stop", flush=True)
    try:
        while not stop.is_set():
            stop.wait(0.5)
    finally:
        adapter.close()
        session.close()
    return 0


def _signals() -> Any:
    import signal
    import threading

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    return stop


def _join(args: argparse.Namespace, stop: Any) -> Any:
    """A Zenoh session, retried every second until a router answers (said once); None if
    ``stop`` was set meanwhile. Once open, a router that goes away and comes back is rejoined
    by Zenoh itself (the retry settings of :func:`service.zconfig.network_config`)."""
    import zenoh

    from armd.service.zconfig import network_config

    connect = args.connect or ([] if args.listen or args.config else ["tcp/127.0.0.1:7447"])
    zenoh.init_log_from_env_or("error")
    told = False
    while not stop.is_set():
        try:
            return zenoh.open(network_config(listen=args.listen, connect=connect or None, config_file=args.config))
        except zenoh.ZError as e:
            if not told:
                where = ", ".join(connect) or "the configured endpoints"
                print(f"armd: no Zenoh router answers at {where} yet ({str(e).split(' at ')[0]}); retrying every "
                      "second (Ctrl-C to give up)", file=sys.stderr, flush=True)
                told = True
            stop.wait(1.0)
    return None


def _make_adapter(args: argparse.Namespace, session: object, arm: Robot, port: object = None) -> Any:
    if args.kind == "sim":
        from armd.clients.sim import SimAdapter

        return SimAdapter(session, arm, prefix=args.prefix, time_scale=args.time_scale,  # type: ignore[arg-type]
                          lag=args.lag)
    if args.kind == "ssc32":
        from armd.clients.ssc32 import SSC32Adapter

        return SSC32Adapter(session, arm, args.port, baud=args.baud, prefix=args.prefix,  # type: ignore[arg-type]
                            state_dir=args.state_dir, serial_port=port)
    from armd.clients.grbl import GrblAdapter

    return GrblAdapter(session, arm, args.port, baud=args.baud, prefix=args.prefix,  # type: ignore[arg-type]
                       serial_port=port, assume_rest=args.assume_rest, home=args.home)


def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router on the ``--config`` file's endpoints (TLS and all), ``--listen`` and
    ``--connect`` replacing them where given; with neither, on tcp/127.0.0.1:7447."""
    from armd.service.zconfig import endpoints, network_config

    conf = network_config(listen=args.listen, connect=args.connect, config_file=args.config, mode="router")
    stop = _signals()  # before the line that says it is up: a SIGTERM right after it stops it cleanly
    session = _open(conf)
    listening = ", ".join(endpoints(conf, "listen")) or "no endpoint"
    joined = f", connected to {', '.join(endpoints(conf, 'connect'))}" if endpoints(conf, "connect") else ""
    print(f"zenoh router {session.zid()} listening on {listening}{joined}", flush=True)
    try:
        while not stop.is_set():
            stop.wait(0.5)
    finally:
        session.close()
    return 0


def _client(args: argparse.Namespace) -> object:
    from armd.clients.client import ArmClient

    return ArmClient(args.connect, config=args.config, prefix=args.prefix, timeout=args.timeout)


def _show(args: argparse.Namespace, reply: dict[str, Any], table: list[tuple[str, object]]) -> None:
    if args.json:
        print(json.dumps(reply, indent=2))
        return
    width = max(len(k) for k, _ in table)
    for k, v in table:
        if isinstance(v, float):
            v = f"{v:.6g}"
        elif isinstance(v, list) and v and all(isinstance(x, float) for x in v):
            v = "[" + ", ".join(f"{x:.4f}" for x in v) + "]"
        print(f"{k:<{width}}  {v}")


def cmd_robots(args: argparse.Namespace) -> int:
    with _client(args) as c:  # type: ignore[attr-defined]
        reply = {"robots": c.robots()}
    if args.json:
        print(json.dumps(reply, indent=2))
    else:
        for r in reply["robots"]:
            print(f"{r['name']:<12} {r['title']}  ({', '.join(r['joints'])})")
    return 0


def cmd_ik(args: argparse.Namespace) -> int:
    req: dict[str, Any] = {"target": _numbers(args.xyz, "target")}
    if args.approach is not None:
        req["approach"] = _approach(args.approach)
    if args.seed:
        req["seed"] = _numbers(args.seed, "seed")
    with _client(args) as c:  # type: ignore[attr-defined]
        r = c.call(f"{args.robot}/ik", req)
    _show(args, r, [("status", r["status"]), ("q [rad]", r["q"]), ("position error [m]", r["position_error"]),
                    ("reached [m]", r["reached"]), ("pitch [rad]", r["pitch"]), ("branch", r["branch"]),
                    ("other branches", len(r["branches"])), ("reason", r["reason"] or "")])
    return 0 if r["status"] == "ok" else 1


def cmd_fk(args: argparse.Namespace) -> int:
    with _client(args) as c:  # type: ignore[attr-defined]
        r = c.call(f"{args.robot}/fk", {"q": _numbers(args.q, "q")})
    _show(args, r, [("position [m]", r["position"]), ("pitch [rad]", r["pitch"]),
                    ("within limits", r["within_limits"])])
    return 0


def _goal(args: argparse.Namespace) -> object:
    if (args.goal is None) == (args.target is None):
        raise robots.BadRequest("give exactly one of --goal Q... (joints) or --target X Y Z", field="goal")
    if args.goal is not None:
        return _numbers(args.goal, "goal")
    return {"target": _numbers(args.target, "target"), "approach": _approach(args.approach)}


def cmd_plan(args: argparse.Namespace) -> int:
    req: dict[str, Any] = {"goal": _goal(args), "path": args.path, "speed": args.speed}
    if args.start:
        req["start"] = _numbers(args.start, "start")
    with _client(args) as c:  # type: ignore[attr-defined]
        r = c.call(f"{args.robot}/plan", req)
        if args.plot:
            from armd.clients.client import TrajectoryReply

            c.plot(args.robot, TrajectoryReply.of(r), args.plot)
    _show(args, r, [("path", r["path"]), ("duration [s]", r["duration"]), ("samples", len(r["times"])),
                    ("rate [Hz]", r["rate_hz"]), ("end [rad]", r["position"][-1]), ("end commands", r["commands"][-1])]
          + ([("plot", args.plot)] if args.plot else []))
    return 0


def cmd_move(args: argparse.Namespace) -> int:
    with _client(args) as c:  # type: ignore[attr-defined]
        r = c.call(f"{args.robot}/move", {"goal": _goal(args), "path": args.path, "speed": args.speed})
        if args.wait:
            import numpy as np

            c.wait_until_still(args.robot, np.array(r["goal"]), timeout=r["duration"] + 10.0)
    _show(args, r, [("trajectory", r["id"]), ("path", r["path"]), ("duration [s]", r["duration"]),
                    ("goal [rad]", r["goal"]), ("planned from", r["start_source"])])
    return 0


def cmd_stop(args: argparse.Namespace) -> int:
    with _client(args) as c:  # type: ignore[attr-defined]
        r = c.call(f"{args.robot}/stop")
    _show(args, r, [("trajectory", r["id"]), ("stops in [s]", r["duration"]), ("rest [rad]", r["rest"]),
                    ("adapters", r["adapters"])])
    return 0


def cmd_estop(args: argparse.Namespace) -> int:
    """Straight to the adapters on ``<prefix>/<robot>/estop`` (no service needed); waits
    ``--wait`` seconds for them to say they are stopping."""
    with _client(args) as c:  # type: ignore[attr-defined]
        acks = c.estop(args.robot, wait=args.wait)
    for a in acks:
        print(f"adapter {a['adapter']} ({a['kind']}): stopping, {a.get('duration', 0.0):.3f} s")
    if not acks:
        print(f"armd: no adapter of {args.robot} acknowledged the estop within {args.wait} s", file=sys.stderr)
        return 1
    return 0


def cmd_unlock(args: argparse.Namespace) -> int:
    """An operator's word to an adapter that lost the arm's position (GRBL after a reset or an alarm)."""
    how = "home" if args.home else "assume_rest"
    with _client(args) as c:  # type: ignore[attr-defined]
        answer = c.unlock(args.robot, how, wait=args.wait)
    if answer is None:
        print(f"armd: no adapter of {args.robot} answered the unlock within {args.wait} s", file=sys.stderr)
        return 1
    if answer["event"] != "unlocked":
        print(f"armd: error: {answer.get('reason', answer)}", file=sys.stderr)
        return 1
    print(f"{args.robot}: unlocked ({how})")
    return 0


def _limit_args(p: argparse.ArgumentParser) -> None:
    from armd.service.protocol import Limits

    d = Limits()
    g = p.add_argument_group("limits", "what one request may ask (docs/reliability.md)")
    g.add_argument("--max-payload", type=int, default=d.max_payload_bytes, metavar="BYTES",
                   help=f"largest request payload (default {d.max_payload_bytes:,})")
    g.add_argument("--max-batch", type=int, default=d.max_batch, metavar="N",
                   help=f"most targets in one IK batch (default {d.max_batch:,})")
    g.add_argument("--max-waypoints", type=int, default=d.max_waypoints, metavar="N",
                   help=f"most via points in one plan or move (default {d.max_waypoints})")
    g.add_argument("--max-samples", type=int, default=d.max_samples, metavar="N",
                   help=f"most samples in one trajectory (default {d.max_samples:,})")
    g.add_argument("--max-depth", type=int, default=d.max_depth, metavar="N",
                   help=f"deepest JSON nesting of a request (default {d.max_depth})")
    g.add_argument("--deadline", type=float, default=d.deadline, metavar="SECONDS",
                   help=f"time allowed per request from its arrival, queue included (default {d.deadline:g})")
    g.add_argument("--workers", type=int, default=4, metavar="N",
                   help="threads serving requests (default 4; stop has two of its own)")


def _client_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="default tcp/127.0.0.1:7447")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5)")
    p.add_argument("--prefix", default="armd")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the service")
    p.add_argument("--json", action="store_true", help="print the reply as JSON")


def _motion_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("robot")
    p.add_argument("--goal", nargs="+", metavar="Q", help="goal joint vector [rad]")
    p.add_argument("--target", nargs=3, metavar=("X", "Y", "Z"), help="goal tool point [m] in base")
    p.add_argument("--approach", help="parallel, perpendicular, free or a pitch [rad] (with --target)")
    p.add_argument("--path", choices=["joint", "line"], default="joint")
    p.add_argument("--speed", type=float, default=1.0, help="fraction of the velocity limits, (0, 1]")


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
    _limit_args(p)
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("adapter", help="run a hardware adapter daemon for one arm")
    p.add_argument("kind", choices=["sim", "ssc32", "grbl"],
                   help="sim: a simulated arm; ssc32: servos on an SSC-32; grbl: steppers on GRBL")
    p.add_argument("robot")
    _network_args(p)
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated time per real second (sim)")
    p.add_argument("--lag", type=float, default=0.0, help="first-order servo lag time constant [s] (sim)")
    p.add_argument("--port", help="serial port or pyserial URL (ssc32, grbl)")
    p.add_argument("--baud", type=int, default=None, help="the controller's baud rate (default: the arm's "
                   "[controller] baud)")
    p.add_argument("--state-dir", help="where the adapter keeps the arm's last pose (ssc32; default "
                   "$ARMD_STATE_DIR, else ~/.local/state/armd)")
    known = p.add_mutually_exclusive_group()
    known.add_argument("--assume-rest", action="store_true",
                       help="grbl: the arm is at its rest pose now (I checked): its position is known")
    known.add_argument("--home", action="store_true", help="grbl: run the homing cycle ($H) at start")
    p.set_defaults(func=cmd_adapter)

    p = sub.add_parser("router", help="run a standalone Zenoh router (no zenohd needed)")
    _network_args(p)
    p.set_defaults(func=cmd_router)

    p = sub.add_parser("robots", help="the arms a running service serves")
    _client_args(p)
    p.set_defaults(func=cmd_robots)

    p = sub.add_parser("ik", help="inverse kinematics from the service: armd ik ROBOT X Y Z")
    p.add_argument("robot")
    p.add_argument("xyz", nargs=3, metavar="X/Y/Z", help="target [m] in the arm's base frame")
    p.add_argument("--approach", help="parallel, perpendicular, free or a pitch [rad]")
    p.add_argument("--seed", nargs="+", metavar="Q", help="current joint vector [rad]")
    _client_args(p)
    p.set_defaults(func=cmd_ik)

    p = sub.add_parser("fk", help="forward kinematics from the service: armd fk ROBOT Q...")
    p.add_argument("robot")
    p.add_argument("q", nargs="+", help="joint vector [rad]")
    _client_args(p)
    p.set_defaults(func=cmd_fk)

    p = sub.add_parser("plan", help="plan a trajectory on the service (nothing moves)")
    _motion_args(p)
    p.add_argument("--start", nargs="+", metavar="Q", help="start joint vector (default: where the arm is)")
    p.add_argument("--plot", metavar="FILE.png", help="also write a PNG of the trajectory (limits drawn)")
    _client_args(p)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("move", help="move an arm (needs an adapter: hardware or --sim)")
    _motion_args(p)
    p.add_argument("--wait", action="store_true", help="return when the arm is at rest at the goal")
    _client_args(p)
    p.set_defaults(func=cmd_move)

    p = sub.add_parser("stop", help="stop an arm now")
    p.add_argument("robot")
    _client_args(p)
    p.set_defaults(func=cmd_stop)

    p = sub.add_parser("estop", help="emergency stop, straight to the arm's adapters (no service needed)")
    p.add_argument("robot")
    p.add_argument("--wait", type=float, default=1.0, help="seconds to wait for the adapters to answer")
    _client_args(p)
    p.set_defaults(func=cmd_estop)

    p = sub.add_parser("unlock", help="tell an adapter that lost the arm's position where the arm is")
    p.add_argument("robot")
    how = p.add_mutually_exclusive_group(required=True)
    how.add_argument("--home", action="store_true", help="run the controller's homing cycle ($H)")
    how.add_argument("--assume-rest", action="store_true", help="the arm is at its rest pose: I checked")
    p.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the adapter's answer")
    _client_args(p)
    p.set_defaults(func=cmd_unlock)

    from armd.clients import demo, view, workspace

    workspace.register(sub)
    demo.register(sub)
    view.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except ArmdError as e:  # what armd says is wrong: one line, exit 1 (argparse's usage errors exit 2)
        print(f"armd: error: {e.message}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `armd catalogue | head`: the reader left; stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except ModuleNotFoundError as e:  # an extra this command needs is not installed
        extra = EXTRAS.get((e.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"armd: error: this command needs {e.name}: pip install 'armd[{extra}]'", file=sys.stderr)
        return 1


EXTRAS = {"serial": "hardware", "matplotlib": "view", "meshcat": "view"}  # a module: the extra that installs it


if __name__ == "__main__":
    sys.exit(main())
