"""The commands of an arm moved by hand: ``armd calibrate`` (a bus-servo arm's zeros,
directions and ranges; an SSC-32 arm's centre pulses and directions, by jogging),
``armd record`` (the arm's motion by hand, to a file; or, ``--teleop``, a teleoperated
session heard over the network: the arm's state and its tracking stream's puts) and ``armd
replay`` (that file, through the service: its path as moves, or ``--stream``, its puts again
on the tracking stream)."""

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
MAX_SECONDS = 86_400.0  # [s] the longest recording --seconds asks for
STILL_WAIT = 30.0  # [s] after a stream's last put, how long the arm may take to come to rest


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


def _enter_ends(stop: threading.Event) -> None:
    """Enter sets ``stop`` (a closed input ends nothing: ``--seconds`` or Ctrl-C does)."""

    def on_enter() -> None:
        if sys.stdin.readline():
            stop.set()

    threading.Thread(target=on_enter, name="armd-record-enter", daemon=True).start()


def cmd_record(args: argparse.Namespace) -> int:
    from armd.adapters.by_hand import LIMP, record

    if args.seconds is not None and not 0.0 < args.seconds <= MAX_SECONDS:  # (NaN fails too)
        raise BadRequest(f"--seconds must be in (0, {MAX_SECONDS:g}], got {args.seconds}", field="seconds")
    if args.teleop:
        if args.port or args.baud or args.calibration:
            raise BadRequest(
                "--port, --baud and --calibration go with --adapter (the arm's bus): --teleop hears the arm over "
                "the network",
                field="teleop",
            )
        return _record_teleop(args)
    if not args.port:
        raise BadRequest("--adapter needs --port PORT: the arm's serial port", field="port")
    if args.connect or args.config:
        raise BadRequest("--connect and --config go with --teleop: --adapter reads the arm's bus here", field="connect")
    arm, bus = _bus_arm(args, args.calibration or "")
    stop = signals()

    def ready() -> None:
        ask(LIMP)
        if args.seconds is None:
            say("recording: press Enter to end it")
        _enter_ends(stop)

    rec = record(arm, bus, stop, seconds=args.seconds, say=say, ready=ready)
    out = Path(args.output)
    rec.save(out)
    span = float(rec.times[-1] - rec.times[0])
    say(f"wrote {out}: {len(rec.times)} readings over {span:.1f} s ({(len(rec.times) - 1) / span:.0f} a second)")
    return 0


def _record_teleop(args: argparse.Namespace) -> int:
    """``armd record ROBOT --teleop``: the arm's state and its tracking stream, heard through the
    network until Enter, Ctrl-C or ``--seconds``, to a recording of version 2."""
    from armd.clients import ArmClient
    from armd.clients.session_recorder import SessionRecorder
    from armd.planning.recording import MAX_NAME, Command, Recording

    where = f"{args.prefix}/{args.robot}"
    stop = signals()
    with ArmClient(args.connect, config=args.config, prefix=args.prefix, timeout=args.timeout) as c:
        info = c.info(args.robot)  # (a service that serves the arm, or the error now, in one line)
        joints = tuple(str(j["name"]) for j in info["joints"])
        if not info.get("adapters"):
            raise NoAdapter(
                f"no adapter of {args.robot} is running (armd adapter, or armd serve --sim): nothing says where "
                "the arm is, nothing to record",
                robot=args.robot,
            )
        with SessionRecorder(c.session, args.prefix, args.robot, nq=len(joints)) as rec:
            end = "press Enter to end it" if args.seconds is None else f"for {args.seconds:g} s (Enter ends it sooner)"
            say(f"recording {args.robot}: its state ({where}/state) and its tracking stream ({where}/track); {end}")
            _enter_ends(stop)
            until = None if args.seconds is None else time.monotonic() + args.seconds
            while not stop.is_set() and (until is None or time.monotonic() < until):
                stop.wait(0.1 if until is None else min(0.1, max(until - time.monotonic(), 0.0)))
            heard = rec.heard()
    if len(heard.times) < 2:
        raise NoAdapter(
            f"heard {len(heard.times)} state(s) of {args.robot}: no adapter put it on {where}/state (or this "
            "user may not watch it: docs/security.md); nothing written",
            robot=args.robot,
        )
    state = {"adapter": str(heard.adapter)[:MAX_NAME]}
    if heard.source is not None:
        state["source"] = heard.source[:MAX_NAME]
    recording = Recording(
        args.robot,
        joints,
        heard.times,
        heard.position,
        heard.gripper,
        tuple(Command(t, p) for t, p in heard.commands),
        state,
    )
    out = Path(args.output)
    recording.save(out)
    span = float(heard.times[-1] - heard.times[0])
    say(
        f"wrote {out}: {len(heard.times)} readings over {span:.1f} s ({(len(heard.times) - 1) / span:.0f} a second, "
        f"adapter {heard.adapter}'s {heard.source + ' ' if heard.source else ''}state), {len(heard.commands)} puts in "
        f"{heard.sessions} session(s)"
    )
    if not heard.commands:
        say(
            f"no put was heard on {where}/track: none was put while recording, or this user may not hear them "
            "(docs/security.md); armd replay --stream needs them, armd replay replays the path"
        )
    if heard.skipped:
        say(
            f"the puts' seq skips {heard.skipped} numbers: puts not heard (dropped on the way, as a stream's may be "
            "on a busy machine), or a client that numbers so"
        )
    if heard.other_states:
        say(f"{heard.other_states} states of another adapter of {args.robot} were heard too: not kept")
    if heard.unread:
        say(f"{heard.unread} payloads on {where}/state, track or events could not be read: not kept")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from armd.clients import ArmClient
    from armd.planning.recording import Recording, parts

    arm = robot_named(args.robot, args.robots_dir)
    if not 0.0 <= args.gripper_wait <= 60.0:  # (NaN fails too)
        raise BadRequest(f"--gripper-wait must be in [0, 60] s, got {args.gripper_wait}", field="gripper_wait")
    rec = Recording.load(Path(args.file))
    if args.stream:
        return _replay_stream(args, arm, rec)
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


def _replay_stream(args: argparse.Namespace, arm: Any, rec: Any) -> int:
    """``armd replay ROBOT FILE --stream``: the arm moved to its pose when the stream began (and
    the gripper as it was), then the recorded puts put again at their own pace
    (:class:`armd.clients.stream_replay.StreamReplay`); returns once the arm rests."""
    from armd.clients import ArmClient
    from armd.clients.stream_replay import StreamReplay
    from armd.planning.recording import check, stream_start
    from armd.service.track_message import DEADMAN

    if not rec.commands:
        why = "an arm recorded by hand, version 1" if rec.commands is None else "no put was heard while recording"
        raise BadRequest(
            f"{args.file} has no tracking stream to replay ({why}): replay its path, without --stream", field="commands"
        )
    q = check(rec, arm)  # (its readings: the arm's, inside its limits; the first is where the stream began)
    k = stream_start(rec)
    commands = [(c.t, c.put) for c in rec.commands]
    named = [p["session"] for _, p in commands if isinstance(p.get("session"), str)]
    if not named:
        raise BadRequest(
            f"{args.file}: none of its puts names a session (the service refused them all)", field="commands"
        )
    deadman = next((p["deadman"] for _, p in commands if p.get("session") == named[-1] and "deadman" in p), DEADMAN)
    say(
        f"{args.file}: {len(commands)} puts in {len(set(named))} session(s) over "
        f"{commands[-1][0] - commands[0][0]:.1f} s, put again at their own pace from the arm's pose at "
        f"{rec.times[k]:.2f} s of the recording"
    )
    stop = signals()
    with ArmClient(args.connect, config=args.config, prefix=args.prefix, timeout=args.timeout) as c:
        r = c.move(args.robot, q[k], speed=args.speed)
        # (not before its end: a short move's start is within --arrival of its goal, and a stream
        # put while the arm moves waits for it to rest)
        stop.wait(r.duration)
        c.wait_until_still(args.robot, r.goal, timeout=10.0, tolerance=args.arrival)
        if rec.gripper is not None and arm.gripper is not None:
            _grip(c, args, float(rec.gripper[k]))
        say(f"  at the stream's start ({r.duration:.2f} s): putting")
        with StreamReplay(c.session, args.prefix, args.robot) as replay:
            replay.run(commands, stop)
            stop.wait(float(deadman) if isinstance(deadman, (int, float)) else DEADMAN)  # (the last session's)
            c.wait_until_still(args.robot, timeout=STILL_WAIT)
            events = replay.events
    said: dict[tuple[str, str], list[Any]] = {}
    for e in events:
        if e.status != "started":
            said.setdefault((e.status, e.reason), []).append(e)
    for (status, _), es in said.items():
        say(f"  the service said {status} ({len(es) + sum(e.repeated for e in es)}x): {es[0].message}")
    if stop.is_set():
        print(
            f"armd: the replay stopped after {replay.puts} of {len(commands)} puts: the arm braked to rest at the "
            "deadman",
            file=sys.stderr,
        )
        return 1
    skipped = f" ({replay.skipped} naming no session not put)" if replay.skipped else ""
    say(f"replayed {args.file} on {args.robot}: {replay.puts} puts in {replay.sessions} session(s){skipped}")
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
        "record",
        parents=[log_args],
        help="record a bus-servo arm moved by hand (torque off), or a teleoperated session (--teleop), to a JSON file",
    )
    p.add_argument("robot")
    how = p.add_mutually_exclusive_group(required=True)
    how.add_argument("--adapter", choices=list(BUS_SERVOS), help="the arm's bus: the arm moved by hand, torque off")
    how.add_argument(
        "--teleop",
        action="store_true",
        help="a teleoperated session, heard through the network: the arm's state (from its adapter) and the puts "
        "on its tracking stream, with their times (armd serve and the arm's adapter running)",
    )
    p.add_argument("--port", help="--adapter: the serial port (no adapter may be running on it)")
    p.add_argument("--baud", type=int, help="--adapter: default: the arm's [controller] baud")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument(
        "--calibration", help="--adapter: the arm's calibration.toml (default: the one armd calibrate wrote)"
    )
    p.add_argument("-o", "--output", required=True, help="the recording's file (JSON)")
    p.add_argument("--seconds", type=float, help="end after this long (default: when Enter is pressed)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="--teleop: default tcp/127.0.0.1:7447")
    p.add_argument("--config", help="--teleop: a Zenoh configuration file (JSON5: credentials, TLS)")
    p.add_argument("--prefix", default="armd")
    p.add_argument("--timeout", type=float, default=5.0, help="--teleop: seconds to wait for the service")
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
    p.add_argument(
        "--stream",
        action="store_true",
        help="put the recorded commands again on the tracking stream, at their own pace (a recording of armd record "
        "--teleop), after a move to the arm's pose where the stream began; --speed: that move's",
    )
    _client_args(p)
    p.set_defaults(func=cmd_replay, log_default="warning")
