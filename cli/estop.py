"""``armd estop ROBOT``: the emergency stop from the command line, put straight to the arm's
adapters on ``<prefix>/<robot>/estop`` (no service needed), each of which brakes the arm from
its own state and says ``accepted``.

Fast, because a stop is wanted now: the command line's other commands load NumPy, Pinocchio
and the catalogue (0.3 s before anything is sent); this one, dispatched before any of that
(:func:`wanted`, from :func:`armd.cli.main.main`), imports Zenoh and the network configuration
only and puts the stop as soon as the session is open, at Zenoh's real-time priority. (So it
does not use :class:`~armd.clients.ArmClient`, whose import is NumPy's; ``ArmClient.estop``
puts the same message, and is what a resident program, which has its session open, calls.)
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
import uuid
from collections.abc import Sequence
from typing import Any

from .logs import LOG_LEVELS, set_up_logging

HELP = "emergency stop, straight to the arm's adapters (no service needed)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("robot")
    p.add_argument("--wait", type=float, default=1.0, help="seconds to wait for the adapters to answer")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="default tcp/127.0.0.1:7447")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5)")
    p.add_argument("--prefix", default="armd")
    p.add_argument("--timeout", type=float, default=5.0, help=argparse.SUPPRESS)  # (as the other calls take it)
    p.add_argument("--json", action="store_true", help="print the adapters' answers as JSON")


def run(args: argparse.Namespace) -> int:
    """Put the estop; wait ``args.wait`` [s] for the adapters' ``accepted`` events, and print them."""
    import zenoh

    from armd.errors import NoReply
    from armd.service.zconfig import client_config

    prefix = args.prefix.rstrip("/")
    ident = uuid.uuid4().hex
    got: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on_event(sample: zenoh.Sample) -> None:
        try:
            event = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        if isinstance(event, dict) and event.get("event") == "accepted" and event.get("id") == ident:
            with lock:
                got.append(event)

    try:
        session = zenoh.open(client_config(args.connect, args.config))
    except zenoh.ZError as e:
        raise NoReply(
            f"cannot reach an armd network at {', '.join(args.connect or ['tcp/127.0.0.1:7447'])}: {e}"
        ) from None
    try:
        # (the answers' subscriber first: declared on the same link, the router has it before the stop)
        sub = session.declare_subscriber(f"{prefix}/{args.robot}/events", on_event) if args.wait > 0 else None
        session.put(
            f"{prefix}/{args.robot}/estop",
            json.dumps({"id": ident, "by": "armd estop"}),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.REAL_TIME,
        )
        if sub is not None:
            time.sleep(args.wait)
            sub.undeclare()
    finally:
        session.close()
    with lock:
        acks = list(got)
    for a in acks:
        if args.json:
            print(json.dumps(a))
        else:
            print(f"adapter {a['adapter']} ({a['kind']}): stopping, {a.get('duration', 0.0):.3f} s")
    if not acks and args.wait > 0:
        print(f"armd: no adapter of {args.robot} acknowledged the estop within {args.wait} s", file=sys.stderr)
        return 1
    return 0


def wanted(argv: Sequence[str]) -> bool:
    """Whether the command line ``argv`` (without the program) asks for ``estop``."""
    words = list(argv)
    while words and words[0].startswith("-"):  # (options before the command: --log-level LEVEL)
        words = words[2:] if words[0] == "--log-level" else words[1:]
    return bool(words) and words[0] == "estop"


def main(argv: Sequence[str]) -> int:
    """``armd [--log-level L] estop ROBOT ...``, the same options as through :func:`armd.cli.main.main`."""
    from armd.errors import ArmdError

    parser = argparse.ArgumentParser(prog="armd")
    parser.add_argument("--log-level", choices=LOG_LEVELS, default=None)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("estop", help=HELP)
    p.add_argument("--log-level", choices=LOG_LEVELS, default=argparse.SUPPRESS, help="what armd logs to stderr")
    add_arguments(p)
    args = parser.parse_args(list(argv))
    set_up_logging(args.log_level or "warning")
    try:
        return run(args)
    except ArmdError as e:
        print(f"armd: error: {e.message}", file=sys.stderr)
        return 1
