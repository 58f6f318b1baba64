"""The ``armd`` command line: the top of the layers, wiring the service, the adapters, the
client and the tools. One parser, one logging set-up (``--log-level``, before or after the
command), and one way out: an armd error is one line and exit 1, a usage error exit 2."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from armd.errors import ArmdError

from . import estop
from .logs import LOG_LEVELS, set_up_logging

EXTRAS = {
    "serial": "hardware",
    "scservo_sdk": "hardware",
    "matplotlib": "view",
    "meshcat": "view",
}  # a module: the extra that installs it


def build_parser() -> argparse.ArgumentParser:
    from . import calls, daemons, offline, teach, teleop, tools  # (here: `armd estop` never loads them)

    parser = argparse.ArgumentParser(prog="armd", description="IK and motion service for small robot arms")
    parser.add_argument(
        "--log-level",
        choices=LOG_LEVELS,
        default=None,
        help="what armd logs to stderr (default: info for the daemons, the viewer and the "
        "router; warning for the rest)",
    )
    log_args = argparse.ArgumentParser(add_help=False)  # --log-level after the command, too
    log_args.add_argument("--log-level", choices=LOG_LEVELS, default=argparse.SUPPRESS, help="what armd logs to stderr")
    sub = parser.add_subparsers(dest="command", required=True)
    offline.register(sub, log_args)
    daemons.register(sub, log_args)
    calls.register(sub, log_args)
    tools.register(sub, log_args)
    teach.register(sub, log_args)
    teleop.register(sub, log_args)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    if estop.wanted(words):  # a stop, now: before NumPy, Pinocchio and the catalogue are loaded
        return estop.main(words)
    parser = build_parser()
    args = parser.parse_args(words)
    set_up_logging(args.log_level or getattr(args, "log_default", "warning"))
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
