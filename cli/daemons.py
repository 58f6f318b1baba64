"""The long-running commands: ``armd serve`` (the service, with simulated arms on ``--sim``),
``armd adapter`` (a hardware adapter daemon for one arm) and ``armd router``."""

from __future__ import annotations

import argparse
import sys
import threading
from typing import Any

from armd.errors import ArmdError, BadRequest, RobotFileError
from armd.robots import Robot

from .common import (
    BUS_SERVOS,
    all_robots,
    close_session,
    network_args,
    open_bus,
    open_session,
    raise_open_files,
    robot_named,
    signals,
    wait_for_signal,
    where,
)


def cmd_serve(args: argparse.Namespace) -> int:
    from armd.service.protocol import Limits
    from armd.service.server import Service
    from armd.service.zconfig import network_config

    limits = Limits(
        max_payload_bytes=args.max_payload,
        max_batch=args.max_batch,
        max_depth=args.max_depth,
        max_waypoints=args.max_waypoints,
        max_samples=args.max_samples,
        deadline=args.deadline,
    )
    if args.workers < 1:
        raise BadRequest(f"--workers must be >= 1, got {args.workers}", field="workers")
    from armd.service.server import SWITCH_INTERVAL

    # (the GIL handed over every 0.5 ms, not 5: a stop's thread waits that long behind each
    # request that computes, at every step of its path)
    sys.setswitchinterval(SWITCH_INTERVAL)
    raise_open_files()
    refused: dict[str, RobotFileError] = {}  # (a bad arm of --robots-dir: said in the log, the others served)
    arms = all_robots(args.robots_dir, refused)
    world = _sim_objects(args.objects, arms)  # (checked before the network is joined)
    conf = network_config(listen=args.listen, connect=args.connect, config_file=args.config)
    stop = signals()  # before the line that says it is up: a SIGTERM right after it stops it cleanly
    session = open_session(conf)
    try:
        with stop.interrupting("the warm-up"):  # (a signal meanwhile ends the process at once)
            service = Service(session, arms, prefix=args.prefix, limits=limits, workers=args.workers)
    except BaseException:
        close_session(session)  # a Zenoh session left open would keep the process from exiting
        raise
    sims = []
    if args.sim:
        from armd.adapters.sim import SimAdapter

        sims = [
            SimAdapter(session, arm, prefix=args.prefix, time_scale=args.time_scale, objects=world.get(name, []))
            for name, arm in arms.items()
        ]
    extra = f", with simulated arms (x{args.time_scale:g} real time)" if args.sim else ""
    if refused:
        extra += f"; refused (see the log): {', '.join(refused)}"
    print(f"armd serving {', '.join(arms)} on {where(conf)} (prefix {args.prefix}){extra}; Ctrl-C to stop", flush=True)
    try:
        wait_for_signal(stop)
    finally:
        for sim in sims:
            sim.close()
        service.close()
        close_session(session)
    return 0


def cmd_adapter(args: argparse.Namespace) -> int:
    """The port first (a missing or busy one: one line naming it, exit 1), then Zenoh (retried
    until a router answers), then the adapter."""
    arm = robot_named(args.robot, args.robots_dir)
    port: Any = None
    if args.kind != "sim":
        from armd.adapters.serial_port import open_port  # (pyserial: the hardware extra; main() says so)
        from armd.errors import ControllerFault

        if not args.port:
            raise BadRequest(f"the {args.kind} adapter needs --port (e.g. /dev/ttyUSB0)", field="port")
        try:
            if args.kind in BUS_SERVOS:  # (the vendor's SDK opens its port itself)
                from armd.adapters.base import actuators_of
                from armd.robots import BusServo

                actuators_of(arm, BusServo, BUS_SERVOS[args.kind])
                rate = args.baud or int(arm.controller.get("baud", 1_000_000))  # type: ignore[call-overload]
                port = open_bus(args.kind, args.port, rate)
            else:
                baud = args.baud or int(arm.controller.get("baud", 115200))  # type: ignore[call-overload]
                port = open_port(args.port, baud, 0.5, 0.5, exclusive=True)
        except ControllerFault as e:
            print(f"armd: {e.message}", file=sys.stderr)
            return 1
    from armd.service.server import SWITCH_INTERVAL

    sys.setswitchinterval(SWITCH_INTERVAL)  # (the control loop waits at most that long for Python's lock)
    stop = signals()
    session = _join(args, stop)
    if session is None:  # interrupted while waiting for a router
        if port is not None:
            port.close()
        return 0
    try:
        adapter = _make_adapter(args, session, arm, port)
    except ArmdError as e:
        session.close()  # a Zenoh session left open would keep the process from exiting
        print(f"armd: {e.message}", file=sys.stderr)
        return 1
    except BaseException:
        session.close()
        raise
    print(f"armd {args.kind} adapter {adapter.id} driving {args.robot}; Ctrl-C to stop", flush=True)
    try:
        wait_for_signal(stop)
    finally:
        adapter.close()
        close_session(session)
    return 0


def _sim_objects(path: str | None, arms: dict[str, Robot]) -> dict[str, Any]:
    """``--objects FILE``: ``{"<robot>": [{"name", "shape", "size", "position", "yaw"}, ...]}``,
    the objects on each simulated arm's floor (its sensors see them), checked."""
    if not path:
        return {}
    import json
    from pathlib import Path

    from armd.adapters.sim_sensors import objects_of

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise BadRequest(f"--objects {path}: cannot be read: {e}", field="objects") from None
    if not isinstance(data, dict):
        raise BadRequest(f"--objects {path}: must map each arm's name to a list of objects", field="objects")
    unknown = sorted(set(data) - set(arms))
    if unknown:
        raise BadRequest(f"--objects {path}: no arm {', '.join(unknown)} here", field="objects")
    return {name: objects_of(specs, f"objects.{name}") for name, specs in data.items()}


def _join(args: argparse.Namespace, stop: threading.Event) -> Any:
    """A Zenoh session, retried every second until a router answers (said once); None if
    ``stop`` was set meanwhile. Once open, a router that goes away and comes back is rejoined
    by Zenoh itself (the retry settings of :func:`armd.service.zconfig.network_config`)."""
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
                at = ", ".join(connect) or "the configured endpoints"
                print(
                    f"armd: no Zenoh router answers at {at} yet ({str(e).split(' at ')[0]}); retrying every "
                    "second (Ctrl-C to give up)",
                    file=sys.stderr,
                    flush=True,
                )
                told = True
            stop.wait(1.0)
    return None


def _make_adapter(args: argparse.Namespace, session: Any, arm: Robot, port: object = None) -> Any:
    if args.kind == "sim":
        from armd.adapters.sim import SimAdapter

        return SimAdapter(
            session,
            arm,
            prefix=args.prefix,
            time_scale=args.time_scale,
            lag=args.lag,
            objects=_sim_objects(args.objects, all_robots(args.robots_dir)).get(arm.name, []),
        )
    if args.kind in BUS_SERVOS:
        from armd.adapters.dynamixel import DynamixelAdapter
        from armd.adapters.feetech import FeetechAdapter

        cls = FeetechAdapter if args.kind == "feetech" else DynamixelAdapter
        return cls(
            session,
            arm,
            args.port,
            baud=args.baud,
            bus=port,  # type: ignore[arg-type]
            prefix=args.prefix,
            calibration=args.calibration,
        )
    if args.kind == "ssc32":
        from armd.adapters.ssc32 import SSC32Adapter

        return SSC32Adapter(
            session,
            arm,
            args.port,
            baud=args.baud,
            prefix=args.prefix,
            state_dir=args.state_dir,
            serial_port=port,
            calibration=args.calibration,
        )
    from armd.adapters.grbl import GrblAdapter

    return GrblAdapter(
        session,
        arm,
        args.port,
        baud=args.baud,
        prefix=args.prefix,
        serial_port=port,
        assume_rest=args.assume_rest,
        home=args.home,
    )


def cmd_router(args: argparse.Namespace) -> int:
    """A Zenoh router on the ``--config`` file's endpoints (TLS and all), ``--listen`` and
    ``--connect`` replacing them where given; with neither, on tcp/127.0.0.1:7447."""
    from armd.service.zconfig import endpoints, network_config

    conf = network_config(listen=args.listen, connect=args.connect, config_file=args.config, mode="router")
    raise_open_files()
    stop = signals()  # before the line that says it is up: a SIGTERM right after it stops it cleanly
    session = open_session(conf)
    listening = ", ".join(endpoints(conf, "listen")) or "no endpoint"
    joined = f", connected to {', '.join(endpoints(conf, 'connect'))}" if endpoints(conf, "connect") else ""
    print(f"zenoh router {session.zid()} listening on {listening}{joined}", flush=True)
    try:
        wait_for_signal(stop)
    finally:
        close_session(session)
    return 0


def _limit_args(p: argparse.ArgumentParser) -> None:
    from armd.service.protocol import Limits

    d = Limits()
    g = p.add_argument_group("limits", "what one request may ask (docs/reliability.md)")
    g.add_argument(
        "--max-payload",
        type=int,
        default=d.max_payload_bytes,
        metavar="BYTES",
        help=f"largest request payload (default {d.max_payload_bytes:,})",
    )
    g.add_argument(
        "--max-batch",
        type=int,
        default=d.max_batch,
        metavar="N",
        help=f"most targets in one IK batch (default {d.max_batch:,})",
    )
    g.add_argument(
        "--max-waypoints",
        type=int,
        default=d.max_waypoints,
        metavar="N",
        help=f"most via points in one plan or move (default {d.max_waypoints})",
    )
    g.add_argument(
        "--max-samples",
        type=int,
        default=d.max_samples,
        metavar="N",
        help=f"most samples in one trajectory (default {d.max_samples:,})",
    )
    g.add_argument(
        "--max-depth",
        type=int,
        default=d.max_depth,
        metavar="N",
        help=f"deepest JSON nesting of a request (default {d.max_depth})",
    )
    g.add_argument(
        "--deadline",
        type=float,
        default=d.deadline,
        metavar="SECONDS",
        help=f"time allowed per request from its arrival, queue included (default {d.deadline:g})",
    )
    g.add_argument(
        "--workers",
        type=int,
        default=4,
        metavar="N",
        help="threads serving requests (default 4; stop has two of its own)",
    )


def register(sub: Any, log_args: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "serve", parents=[log_args], help="run the service (embeds a Zenoh router unless --connect is given)"
    )
    network_args(p)
    p.add_argument("--robots-dir", help="a folder of your own arms, served with the catalogue")
    p.add_argument(
        "-v",
        "--verbose",
        action="store_const",
        const="debug",
        dest="log_level",
        default=argparse.SUPPRESS,
        help="log one line per request (--log-level debug)",
    )
    p.add_argument("--sim", action="store_true", help="also run a simulated arm (adapter) for every arm")
    p.add_argument(
        "--objects",
        metavar="FILE",
        help='with --sim: objects on the simulated arms\' floors, seen by their sensors: JSON {"<robot>": '
        '[{"name", "shape": "cylinder"|"box"|"sphere", "size", "position": [x, y], "yaw"}]} (docs/sensors.md)',
    )
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated time per real second (with --sim)")
    _limit_args(p)
    p.set_defaults(func=cmd_serve, log_default="info")

    p = sub.add_parser("adapter", parents=[log_args], help="run a hardware adapter daemon for one arm")
    p.add_argument(
        "kind",
        choices=["sim", "ssc32", "grbl", *BUS_SERVOS],
        help="sim: a simulated arm; ssc32: servos on an SSC-32; grbl: steppers on GRBL; "
        "feetech: Feetech STS bus servos (the SO-101); dynamixel: Dynamixel X bus servos, Protocol 2.0",
    )
    p.add_argument("robot")
    network_args(p)
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument("--time-scale", type=float, default=1.0, help="simulated time per real second (sim)")
    p.add_argument("--lag", type=float, default=0.0, help="first-order servo lag time constant [s] (sim)")
    p.add_argument("--objects", metavar="FILE", help="sim: objects on the floor, as armd serve --objects takes")
    p.add_argument("--port", help="serial port or pyserial URL (ssc32, grbl; a serial port for feetech, dynamixel)")
    p.add_argument(
        "--baud", type=int, default=None, help="the controller's baud rate (default: the arm's [controller] baud)"
    )
    p.add_argument(
        "--state-dir",
        help="where the adapter keeps the arm's last pose (ssc32; default $ARMD_STATE_DIR, else ~/.local/state/armd)",
    )
    p.add_argument(
        "--calibration",
        help="ssc32, feetech, dynamixel: the arm's calibration.toml, from armd calibrate "
        "(default: <state dir>/<robot>.calibration.toml, if it exists)",
    )
    known = p.add_mutually_exclusive_group()
    known.add_argument(
        "--assume-rest",
        action="store_true",
        help="grbl: the arm is at its rest pose now (I checked): its position is known",
    )
    known.add_argument("--home", action="store_true", help="grbl: run the homing cycle ($H) at start")
    p.set_defaults(func=cmd_adapter, log_default="info")

    p = sub.add_parser("router", parents=[log_args], help="run a standalone Zenoh router (no zenohd needed)")
    network_args(p)
    p.set_defaults(func=cmd_router, log_default="info")
