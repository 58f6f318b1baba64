"""What the commands share: the arms a command may name, numbers and goals from the command
line, the network options, signals, Zenoh sessions, and the one logging set-up."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import threading
from collections.abc import Iterator
from typing import Any

from armd import robots
from armd.errors import BadRequest, RobotFileError, UnknownRobot
from armd.robots import Robot

from .logs import LOG_FORMAT, LOG_LEVELS, set_up_logging  # noqa: F401 (the commands' one logging set-up)

log = logging.getLogger(__name__)


def all_robots(robots_dir: str | None, refused: dict[str, RobotFileError] | None = None) -> dict[str, Robot]:
    """The catalogue, plus a user's ``--robots-dir`` (which wins on a name). An arm of the
    folder that does not load is said once in the log and left out (into ``refused``, where
    given), and so is the catalogue's arm of its name: the others are served."""
    arms = {name: robots.load(name) for name in robots.names()}
    if robots_dir:
        refused = {} if refused is None else refused
        arms.update(robots.load_dir(robots_dir, refused))
        for name in refused:  # (not the catalogue's arm of that name in its place: another arm)
            arms.pop(name, None)
    return arms


def robot_named(name: str, robots_dir: str | None) -> Robot:
    """The arm ``name``; a refused arm of ``--robots-dir`` raises its own error."""
    refused: dict[str, RobotFileError] = {}
    arms = all_robots(robots_dir, refused)
    if name in refused:
        raise refused[name]
    if name not in arms:
        raise UnknownRobot(name, arms)
    return arms[name]


def numbers(values: list[str], what: str) -> list[float]:
    try:
        return [float(v) for v in values]
    except ValueError:
        raise BadRequest(f"{what} must be numbers, got {' '.join(values)}", field=what) from None


def approach(value: str | None) -> object:
    if value is None or value in ("parallel", "perpendicular", "free"):
        return value
    try:
        return float(value)
    except ValueError:
        raise BadRequest(
            f"approach must be parallel, perpendicular, free or a pitch [rad], got {value!r}", field="approach"
        ) from None


def goal(args: argparse.Namespace) -> object:
    """``--goal Q...`` (joints) or ``--target X Y Z`` (with ``--approach``): exactly one."""
    if (args.goal is None) == (args.target is None):
        raise BadRequest("give exactly one of --goal Q... (joints) or --target X Y Z", field="goal")
    if args.goal is not None:
        return numbers(args.goal, "goal")
    out: dict[str, object] = {"target": numbers(args.target, "target"), "approach": approach(args.approach)}
    if getattr(args, "roll", None) is not None:
        out["roll"] = args.roll
    return out


def motion_args(p: argparse.ArgumentParser) -> None:
    """ROBOT, a goal (``--goal`` joints or ``--target`` point with ``--approach``), the path
    and the speed: what :func:`goal` reads."""
    p.add_argument("robot")
    p.add_argument("--goal", nargs="+", metavar="Q", help="goal joint vector [rad]")
    p.add_argument("--target", nargs=3, metavar=("X", "Y", "Z"), help="goal tool point [m] in base")
    p.add_argument("--approach", help="parallel, perpendicular, free or a pitch [rad] (with --target)")
    p.add_argument("--roll", type=float, help="the tool's roll about its axis [rad] (with --target, a joint path)")
    p.add_argument("--path", choices=["joint", "line"], default="joint")
    p.add_argument("--speed", type=float, default=1.0, help="fraction of the velocity limits, (0, 1]")


def network_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on (default: the --config file's, else tcp/127.0.0.1:7447 for the embedded router)",
    )
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="join an existing Zenoh network through this endpoint instead of embedding a router",
    )
    p.add_argument(
        "--config",
        help="a Zenoh configuration file (JSON5), used as it is: its endpoints, TLS, "
        "credentials; --listen/--connect, where given, replace its endpoints",
    )
    p.add_argument("--prefix", default="armd", help="key expression prefix (default armd)")


BUS_SERVOS = {"feetech": "Feetech", "dynamixel": "Dynamixel"}  # the bus-servo adapters: their vendors


def open_bus(kind: str, port: str, baud: int) -> Any:
    """The vendor's bus ``kind`` (a key of :data:`BUS_SERVOS`) on ``port`` at ``baud``, through its SDK."""
    if kind == "feetech":
        from armd.adapters.feetech import FeetechBus

        return FeetechBus(port, baud)
    from armd.adapters.dynamixel import DynamixelBus

    return DynamixelBus(port, baud)


class Stop(threading.Event):
    """Set by SIGTERM or SIGINT (Ctrl-C) (:func:`signals`). Inside :meth:`interrupting`, the
    signal also ends the process at once, exit status 0: a service's warm-up (the compiler's on
    a first start without the native build, about a minute) never delays a stop. It ends it
    with ``os._exit``, as nothing is declared yet and nothing is to be saved: an exception would
    not do, as the compiler's callbacks (ctypes) swallow it."""

    interrupt = ""  # what is interrupted: said in the log

    @contextlib.contextmanager
    def interrupting(self, what: str) -> Iterator[None]:
        if self.is_set():
            self._exit(what)
        self.interrupt = what
        try:
            yield
        finally:
            self.interrupt = ""

    def signalled(self, *_: object) -> None:
        self.set()
        if self.interrupt:
            self._exit(self.interrupt)

    @staticmethod
    def _exit(what: str) -> None:
        log.info("stopped during %s", what)
        for handler in logging.getLogger().handlers:
            handler.flush()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


def signals() -> Stop:
    """A :class:`Stop` set by SIGTERM or SIGINT (Ctrl-C)."""
    import signal

    stop = Stop()
    signal.signal(signal.SIGTERM, stop.signalled)
    signal.signal(signal.SIGINT, stop.signalled)
    return stop


def wait_for_signal(stop: threading.Event | None = None) -> None:
    """Until SIGTERM or SIGINT."""
    stop = stop or signals()
    while not stop.is_set():
        stop.wait(0.5)


CLOSE_WAIT = 5.0  # [s] a daemon stopping waits this long for its Zenoh session to close, then exits anyway


def close_session(session: Any, wait: float = CLOSE_WAIT) -> None:
    """Close a daemon's Zenoh session, but wait at most ``wait`` seconds: Zenoh's close can
    block on a link it cannot tear down (eclipse-zenoh/zenoh#2675), and a SIGTERM must stop the
    daemon. Exiting closes its sockets anyway: its peers see the link drop (an adapter's token
    with it)."""
    done = threading.Event()

    def close() -> None:
        try:
            session.close()
        except Exception:  # (closed already, or Zenoh's own timeout)
            log.debug("closing the Zenoh session failed", exc_info=True)
        finally:
            done.set()

    threading.Thread(target=close, name="zenoh-close", daemon=True).start()
    if not done.wait(wait):
        log.warning("the Zenoh session did not close in %.0f s: exiting anyway", wait)


def open_session(conf: Any) -> Any:
    """A Zenoh session on ``conf``, after one warning line on stderr where it listens on the
    network with no authentication (:func:`armd.service.zconfig.exposure_warning`); an endpoint
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
        raise BadRequest(f"Zenoh cannot open the session: {str(e).split(' at /')[0]}") from None


def where(conf: Any) -> str:
    """Where a session on ``conf`` is: its connect endpoints, else its listen endpoints."""
    from armd.service.zconfig import endpoints

    return ", ".join(endpoints(conf, "connect") or endpoints(conf, "listen")) or "no endpoint"


def raise_open_files() -> None:
    """A router's open-file limit raised to hold ``MAX_SESSIONS`` sessions (a socket each) where
    the system's hard limit allows: a soft limit of 1,024 (many systems') would cap them first."""
    import resource

    from armd.service.zconfig import MAX_SESSIONS

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = MAX_SESSIONS + 1024  # (and the process's own files)
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    if soft != resource.RLIM_INFINITY and soft < want:
        with contextlib.suppress(ValueError, OSError):  # (not allowed here: the system's limit stands)
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
