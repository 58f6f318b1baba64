"""The tools' commands: ``armd demo`` (the service, simulated arms and a scripted session)
and ``armd view`` (a live 3-D view of one arm in the browser)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import robot_named, wait_for_signal


def cmd_demo(args: argparse.Namespace) -> int:
    from armd.tools import demo

    demo.run(
        args.robots,
        Path(args.out),
        time_scale=args.time_scale,
        workspace_step=args.workspace_step,
        say=lambda line: print(line, flush=True),
    )
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    import zenoh

    from armd.errors import ViewerError
    from armd.service.zconfig import DEFAULT_ENDPOINT, client_config
    from armd.tools.view import ArmView, ZenohFeed

    arm = robot_named(args.robot, args.robots_dir)
    conf = client_config(args.connect, args.config)
    zenoh.init_log_from_env_or("error")
    where = ", ".join(args.connect or ([] if args.config else [DEFAULT_ENDPOINT])) or args.config
    with ArmView(arm, port=args.port, max_rate_hz=args.rate) as view:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as e:
            raise ViewerError(f"cannot reach a Zenoh network at {where}: is `armd serve` running? ({e})") from None
        try:
            with ZenohFeed(view, session, prefix=args.prefix) as feed:
                print(
                    f"armd view of {arm.name}: open {view.url}\n  showing {feed.base}/state and "
                    f"{feed.base}/trajectory from {where}; Ctrl-C to stop",
                    flush=True,
                )
                wait_for_signal()
        finally:
            session.close()
    return 0


def register(sub: Any, log_args: argparse.ArgumentParser) -> None:
    from armd.tools.view import DEFAULT_PORT, HOST

    p = sub.add_parser(
        "demo", parents=[log_args], help="run the service with simulated arms and a scripted session on every arm"
    )
    p.add_argument("robots", nargs="*", help="arms to show (default: the whole catalogue)")
    p.add_argument("--out", default="armd-demo", help="folder for the plots and demo.json (default armd-demo)")
    p.add_argument("--time-scale", type=float, default=2.0, help="simulated time per real second (default 2)")
    p.add_argument("--workspace-step", type=float, default=0.008, help="workspace map cell size [m]")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("view", parents=[log_args], help="a live 3-D view of an arm in the browser (meshcat)")
    p.add_argument("robot")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="default tcp/127.0.0.1:7447")
    p.add_argument("--config", help="a Zenoh configuration file (JSON5)")
    p.add_argument("--prefix", default="armd", help="key expression prefix (default armd)")
    p.add_argument("--robots-dir", help="a folder of your own arms")
    p.add_argument(
        "--port",
        type=int,
        default=None,
        help=f"the viewer's HTTP port on {HOST} (default {DEFAULT_PORT}, or the next free one)",
    )
    p.add_argument("--rate", type=float, default=30.0, help="most display updates per second (default 30)")
    p.set_defaults(func=cmd_view, log_default="info")
