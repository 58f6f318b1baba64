"""``armd teleop ROBOT``: the arm driven by hand through its tracking stream, from one source:
a leader arm (``--leader feetech|dynamixel --leader-port PORT``), the keyboard (``--keyboard``,
in this terminal) or a gamepad (``--gamepad [DEVICE]``). The sources and the loop they share:
:mod:`armd.tools.teleop`."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from armd.errors import BadRequest

from .common import BUS_SERVOS, open_bus, robot_named, signals

LEADER_HZ = 100.0  # [Hz] a leader's reads (a sync read each) and puts, by default
JOG_HZ = 50.0  # [Hz] the keyboard's and the gamepad's puts, by default


def say(line: str) -> None:
    print(f"armd teleop: {line}", flush=True)


def cmd_teleop(args: argparse.Namespace) -> int:
    from armd.clients import ArmClient

    if args.rate is not None and not 1.0 <= args.rate <= 500.0:  # (NaN fails too)
        raise BadRequest(f"--rate must be in [1, 500] Hz, got {args.rate}", field="rate")
    if args.speed is not None and not 0.001 <= args.speed <= 1.0:
        raise BadRequest(f"--speed must be in [0.001, 1], got {args.speed}", field="speed")
    if args.deadman is not None and not 0.05 <= args.deadman <= 1.0:
        raise BadRequest(f"--deadman must be in [0.05, 1] s, got {args.deadman}", field="deadman")
    if not 0.05 <= args.repeat_delay <= 3.0:
        raise BadRequest(f"--repeat-delay must be in [0.05, 3] s, got {args.repeat_delay}", field="repeat_delay")
    if args.leader is None and (args.leader_port or args.leader_robot or args.leader_calibration or args.leader_baud):
        raise BadRequest("--leader-port, --leader-robot, --leader-calibration and --leader-baud go with --leader")
    if args.leader is not None and not args.leader_port:
        raise BadRequest("--leader needs --leader-port PORT: the leader arm's serial port", field="leader_port")
    if args.keyboard and not (sys.stdin.isatty() and sys.stdout.isatty()):
        raise BadRequest("armd teleop --keyboard runs in a terminal (its input and its output)", field="keyboard")
    follower = robot_named(args.robot, args.robots_dir)
    with ArmClient(args.connect, config=args.config, prefix=args.prefix, timeout=args.timeout) as client:
        client.info(args.robot)  # (a service that serves the arm, or the error now, in one line)
        if args.leader is not None:
            return _leader(args, client, follower)
        if args.keyboard:
            return _keyboard(args, client, follower)
        return _gamepad(args, client, follower)


def _stream(args: argparse.Namespace, client: Any, rate: float, **more: Any) -> Any:
    from armd.tools.teleop.stream import Stream

    return Stream(client, args.robot, rate_hz=args.rate or rate, deadman=args.deadman, speed=args.speed, **more)


def _print_event(robot: str) -> Any:
    def show(e: Any) -> None:
        if e.status != "started":
            say(f"{robot}: {e.status}: {e.message}")

    return show


def _leader(args: argparse.Namespace, client: Any, follower: Any) -> int:
    from armd.adapters.base import actuators_of, calibrated
    from armd.robots import BusServo
    from armd.service.track_message import DEADMAN
    from armd.tools.teleop.leader import Leader, leader_calibration_file
    from armd.tools.teleop.leader_map import JointMap, PoseMap

    from .teach import ask

    name = args.leader_robot or args.robot
    leader = robot_named(name, args.robots_dir)
    actuators_of(leader, BusServo, BUS_SERVOS[args.leader])
    path = args.leader_calibration or leader_calibration_file(leader, args.state_dir)
    if args.leader_calibration or path.exists():
        leader = calibrated(leader, path)
        say(f"the leader {name}'s calibration: {path}")
    else:
        say(
            f"no calibration of the leader {name} at {path}: robot.toml's factory zeros (calibrate it: armd "
            f"calibrate {name} --adapter {args.leader} --port {args.leader_port} --output {path})"
        )
    mapping = JointMap(leader, follower) if name == args.robot else PoseMap(leader, follower)
    baud = args.leader_baud or int(leader.controller.get("baud", 1_000_000))  # type: ignore[call-overload]
    source = Leader(
        leader,
        lambda: open_bus(args.leader, args.leader_port, baud),
        mapping,
        ask=ask,
        name=f"the leader {name} on {args.leader_port}",
        lost_after=args.deadman or DEADMAN,
    )
    stream = _stream(args, client, LEADER_HZ, say=say, on_event=_print_event(args.robot))
    stop = signals()
    source.start()
    try:
        how = "joint to joint" if isinstance(mapping, JointMap) else "by its tool point"
        say(f"{source.name}: torque off, read {args.rate or LEADER_HZ:g} times a second; {args.robot} follows {how}")
        stream.run(source, stop)
    finally:
        source.close()
    say(f"ended: {stream.puts} puts in {stream.sessions} session(s)")
    return 0


def _keyboard(args: argparse.Namespace, client: Any, follower: Any) -> int:
    import curses

    from armd.tools.teleop.keyboard import ArmState, Keyboard

    stop = signals()
    done: list[Any] = []

    def run(screen: Any) -> None:
        curses.set_escdelay(25)
        kb = Keyboard(screen, follower, ArmState(client.session, args.prefix, args.robot), first=args.repeat_delay)
        stream = _stream(args, client, JOG_HZ, say=kb.note, on_event=kb.event)
        done.append(stream)
        try:
            stream.run(kb, stop)
        finally:
            kb.close()

    try:
        curses.wrapper(run)
    except curses.error as e:  # (a terminal curses does not know: TERM)
        raise BadRequest(f"this terminal cannot show the keyboard's screen: {e}", field="keyboard") from None
    if done:
        say(f"ended: {done[0].puts} puts in {done[0].sessions} session(s)")
    return 0


def _gamepad(args: argparse.Namespace, client: Any, follower: Any) -> int:
    from armd.tools.teleop.gamepad import EvdevPad, Gamepad
    from armd.tools.teleop.jog import Jog

    device = None if args.gamepad == "auto" else args.gamepad
    source = Gamepad(Jog(follower), lambda: EvdevPad(device))
    stream = _stream(args, client, JOG_HZ, say=say, on_event=_print_event(args.robot))
    stop = signals()
    source.start()
    try:
        say(f"{source.name}: left stick forward/back, left/right; triggers up/down; right stick pitch, roll; B stops")
        stream.run(source, stop)
    finally:
        source.close()
    say(f"ended: {stream.puts} puts in {stream.sessions} session(s)")
    return 0


def register(sub: Any, log_args: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "teleop",
        parents=[log_args],
        help="drive an arm by hand through its tracking stream: a leader arm, the keyboard or a gamepad",
    )
    p.add_argument("robot", help="the arm driven (the follower)")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--leader", choices=list(BUS_SERVOS), help="a leader arm on this bus, read with its torque off")
    source.add_argument("--keyboard", action="store_true", help="jog from the keyboard, in this terminal")
    source.add_argument(
        "--gamepad",
        nargs="?",
        const="auto",
        metavar="DEVICE",
        help="jog from a gamepad (evdev: the first found, or /dev/input/eventN); needs the gamepad extra",
    )
    p.add_argument("--leader-port", help="the leader's serial port (no adapter may be running on it)")
    p.add_argument(
        "--leader-robot", help="the leader's arm (default: the follower's; another arm leads by its tool point)"
    )
    p.add_argument(
        "--leader-calibration",
        help="the leader's calibration.toml (default: <robot>.leader.calibration.toml in the adapters' state dir)",
    )
    p.add_argument("--leader-baud", type=int, help="default: the leader's [controller] baud")
    p.add_argument("--state-dir", help="where the leader's calibration is looked for (default $ARMD_STATE_DIR, ...)")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument("--rate", type=float, help="puts a second (default: 100 for a leader, 50 for a jog)")
    p.add_argument("--speed", type=float, help="a fraction of the arm's limits, (0, 1] (default 1)")
    p.add_argument("--deadman", type=float, help="[s] the arm brakes when no put came for this long (default 0.25)")
    p.add_argument(
        "--repeat-delay",
        type=float,
        default=0.7,
        help="[s] the keyboard: a key counts as held this long after its press, until the terminal repeats it "
        "(default 0.7: past most desktops' first delay)",
    )
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="default tcp/127.0.0.1:7447")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5)")
    p.add_argument("--prefix", default="armd")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the service")
    p.set_defaults(func=cmd_teleop, log_default="warning")
