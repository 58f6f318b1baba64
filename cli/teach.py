"""The commands of an arm moved by hand: ``armd calibrate`` (a bus-servo arm's zeros,
directions and ranges; an SSC-32 arm's centre pulses and directions, by jogging),
``armd record`` (the arm's motion by hand, to a file) and ``armd replay`` (that file, through
the service)."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

from armd.errors import ArmdError, BadRequest, NoAdapter

from .common import BUS_SERVOS, open_bus, robot_named, signals

GRIPPER_CONFIRM = 2.0  # [s] how long an adapter may take to say it commanded the gripper


def say(line: str) -> None:
    print(line, flush=True)


def ask(prompt: str) -> None:
    """``prompt`` on its own line; returns when the operator presses Enter (a closed input: abandoned)."""
    print(f"> {prompt}", flush=True)
    if not sys.stdin.readline():
        raise BadRequest("abandoned: the input closed before the answer", field="stdin")


def _bus_arm(args: argparse.Namespace, calibration: str | None) -> tuple[Any, Any]:
    """The arm (its calibration applied, where it has one) and its bus, opened."""
    from armd.adapters.base import actuators_of, calibrated
    from armd.robots import BusServo

    arm = robot_named(args.robot, args.robots_dir)
    actuators_of(arm, BusServo, BUS_SERVOS[args.adapter])
    if calibration is not None:
        arm = calibrated(arm, calibration or None)
    baud = args.baud or int(arm.controller.get("baud", 1_000_000))  # type: ignore[call-overload]
    return arm, open_bus(args.adapter, args.port, baud)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from armd.robots import calibration as robots_calibration

    if args.adapter == "ssc32":
        from armd.adapters.ssc32_jog import jog

        arm = robot_named(args.robot, args.robots_dir)
        out = Path(args.output) if args.output else None
        path = jog(arm, args.port, args.baud, ask_line, say, output=out, state_dir=args.state_dir)
        say(f"wrote {path}: the SSC-32 adapter reads it at start")
        return 0
    from armd.adapters.base import calibration_file
    from armd.adapters.by_hand import calibrate

    arm, bus = _bus_arm(args, None)
    values, gripper = calibrate(arm, bus, ask, say)
    path = Path(args.output) if args.output else calibration_file(arm, args.state_dir)
    robots_calibration.write(path, values, gripper)
    for name, (zero, direction, (lo, hi)) in values.items():
        say(f"  {name}: zero {zero:g}, direction {direction:+d}, range [{lo:g}, {hi:g}] counts")
    if gripper is not None:
        say(f"  gripper: closed {gripper[0]:g}, open {gripper[1]:g} counts")
    say(f"wrote {path}: the {args.adapter} adapter reads it at start")
    return 0


def ask_line(prompt: str) -> str:
    """``prompt`` on its own line; the operator's answer (a closed input: abandoned)."""
    print(f"> {prompt}", flush=True)
    line = sys.stdin.readline()
    if not line:
        raise BadRequest("abandoned: the input closed before the answer", field="stdin")
    return line.strip()


def cmd_record(args: argparse.Namespace) -> int:
    from armd.adapters.by_hand import LIMP, record

    arm, bus = _bus_arm(args, args.calibration or "")
    stop = signals()

    def on_enter() -> None:
        if sys.stdin.readline():  # (a closed input ends nothing: --seconds or Ctrl-C does)
            stop.set()

    def ready() -> None:
        ask(LIMP)
        if args.seconds is None:
            say("recording: press Enter to end it")
        threading.Thread(target=on_enter, name="armd-record-enter", daemon=True).start()

    rec = record(arm, bus, stop, seconds=args.seconds, say=say, ready=ready)
    out = Path(args.output)
    rec.save(out)
    span = float(rec.times[-1] - rec.times[0])
    say(f"wrote {out}: {len(rec.times)} readings over {span:.1f} s ({(len(rec.times) - 1) / span:.0f} a second)")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from armd.clients import ArmClient
    from armd.planning.recording import Recording, parts

    arm = robot_named(args.robot, args.robots_dir)
    if not 0.0 <= args.gripper_wait <= 60.0:  # (NaN fails too)
        raise BadRequest(f"--gripper-wait must be in [0, 60] s, got {args.gripper_wait}", field="gripper_wait")
    rec = Recording.load(Path(args.file))
    todo = parts(rec, arm, tolerance=args.tolerance, max_via=args.max_via)
    vias = sum(len(p.via) for p in todo)
    say(
        f"{args.file}: {len(rec.times)} readings over {rec.times[-1] - rec.times[0]:.1f} s, replayed as "
        f"{len(todo)} moves through {vias} via points (within {args.tolerance:g} rad)"
    )
    total = 0.0
    with ArmClient(args.connect, config=args.config, prefix=args.prefix, timeout=args.timeout) as c:
        for k, p in enumerate(todo):
            what = "to the recording's start" if k == 0 else f"{p.start_time:.2f}-{p.end_time:.2f} s of the recording"
            try:
                r = c.move(args.robot, p.goal, via=p.via, speed=args.speed)
                c.wait_until_still(args.robot, r.goal, timeout=r.duration + 10.0, tolerance=args.arrival)
            except ArmdError:
                print(f"armd: the replay stopped at move {k + 1}/{len(todo)} ({what})", file=sys.stderr)
                raise
            total += r.duration
            grip = ""
            if p.gripper is not None and arm.gripper is not None:
                _grip(c, args, p.gripper)
                grip = f", gripper {p.gripper:.2f}"
            say(f"  move {k + 1}/{len(todo)}: {what}, {len(p.via)} via, {r.duration:.2f} s{grip}")
    say(f"replayed {args.file} on {args.robot}: {total:.1f} s of motion")
    return 0


def _grip(c: Any, args: argparse.Namespace, opening: float) -> None:
    """The gripper to ``opening``, once an adapter says it commanded it (its event ``gripper``),
    and ``--gripper-wait`` more for it to get there: the next move does not start with the
    gripper on its way."""
    done = threading.Event()
    asked: list[str] = []
    seen: list[str] = []

    def on_event(sample: Any) -> None:
        try:
            e = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        if isinstance(e, dict) and e.get("event") == "gripper":
            seen.append(str(e.get("id")))
            if asked and asked[0] in seen:
                done.set()

    sub = c.session.declare_subscriber(f"{args.prefix}/{args.robot}/events", on_event)
    try:
        asked.append(str(c.gripper(args.robot, opening)["id"]))
        if asked[0] in seen:
            done.set()
        if not done.wait(GRIPPER_CONFIRM):
            raise NoAdapter(
                f"no adapter of {args.robot} said it moved the gripper within {GRIPPER_CONFIRM:g} s", robot=args.robot
            )
    finally:
        sub.undeclare()
    time.sleep(args.gripper_wait)


def register(sub: Any, log_args: argparse.ArgumentParser) -> None:
    from .calls import _client_args

    p = sub.add_parser(
        "calibrate",
        parents=[log_args],
        help="measure an arm's calibration with it in your hands (bus servos: zeros, directions, ranges; "
        "SSC-32: centre pulses and directions, by jogging)",
    )
    p.add_argument("robot")
    p.add_argument("--adapter", required=True, choices=[*BUS_SERVOS, "ssc32"], help="the arm's controller")
    p.add_argument("--port", required=True, help="the serial port (no adapter may be running on it)")
    p.add_argument("--baud", type=int, help="default: the arm's [controller] baud")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument(
        "--output",
        help="where to write it (default: the adapters' state dir, $ARMD_STATE_DIR or ~/.local/state/armd, "
        "<robot>.calibration.toml: read by the adapter at start)",
    )
    p.add_argument("--state-dir", help="the adapters' state dir, where it is written (default $ARMD_STATE_DIR, ...)")
    p.set_defaults(func=cmd_calibrate, log_default="warning")

    p = sub.add_parser(
        "record", parents=[log_args], help="record a bus-servo arm moved by hand (torque off), to a JSON file"
    )
    p.add_argument("robot")
    p.add_argument("--adapter", required=True, choices=list(BUS_SERVOS), help="the arm's bus")
    p.add_argument("--port", required=True, help="the serial port (no adapter may be running on it)")
    p.add_argument("--baud", type=int, help="default: the arm's [controller] baud")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument("--calibration", help="the arm's calibration.toml (default: the one armd calibrate wrote)")
    p.add_argument("-o", "--output", required=True, help="the recording's file (JSON)")
    p.add_argument("--seconds", type=float, help="end after this long (default: when Enter is pressed)")
    p.set_defaults(func=cmd_record, log_default="warning")

    p = sub.add_parser(
        "replay", parents=[log_args], help="replay a recording through the service (smoothed, jerk-limited, checked)"
    )
    p.add_argument("robot")
    p.add_argument("file", help="a recording (armd record)")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument(
        "--tolerance", type=float, default=0.01, help="how far [rad] the replay's path may leave the recording's"
    )
    p.add_argument("--speed", type=float, default=1.0, help="fraction of the velocity limits (default 1)")
    p.add_argument("--max-via", type=int, default=50, help="most via points in one move (default 50, at most 100)")
    p.add_argument(
        "--gripper-wait",
        type=float,
        default=0.5,
        help="seconds the gripper is given to get where it is sent before the arm moves on (default 0.5)",
    )
    p.add_argument(
        "--arrival", type=float, default=0.02, help="how near [rad] each move's end counts as arrived (default 0.02)"
    )
    _client_args(p)
    p.set_defaults(func=cmd_replay, log_default="warning")
