"""What every adapter daemon does on the Zenoh side; the hardware part is a subclass's.

An adapter holds a liveliness token ``<prefix>/<robot>/adapter/<id>`` while it can drive
its arm, takes trajectories from ``<prefix>/<robot>/trajectory`` (each re-checked against
every limit and actuator range: one bad sample rejects the whole trajectory, and nothing
of it reaches the wire), lets a newer trajectory replace the running one, publishes
``<prefix>/<robot>/state`` at ``state_hz`` and ``<prefix>/<robot>/events`` (accepted,
started, done, rejected, aborted, fault, recovered). A controller that stops answering, or
reports an error, is a fault: said once (the event ``fault``; the same reason again is only
counted, and ``recovered`` says how many checks failed and for how long), the token withdrawn
(so ``move`` answers ``no_adapter``) until the controller is well again, the state published
on at its rate (with the fault in it), and an arm in motion braked to rest as a ``stop`` brakes
it, from the adapter's own state (:meth:`Adapter.estimate`: the last it knew, carried on), the
stop running under the fault: never held where it was last seen, which a joint at speed has
passed already and would run back to.

A trajectory is checked by its motion (:mod:`clients.trajectory_message`), then here: its id
runs at most once, its first sample is near where the arm is, and the arm's position must be
known (``homed``; a controller that lost it refuses with ``position_unknown`` until an
operator homes it or confirms its rest pose on ``<prefix>/<robot>/unlock``). A ``stop`` is
never refused: any put on ``<prefix>/<robot>/estop`` (the service's ``stop`` uses it too, and
so does a trajectory of kind ``stop``) brakes the arm from the adapter's own state, within
every limit (:meth:`stop_command`), whatever the service believed. The adapter needs no
service to run what it accepted: if the service dies mid-move, the move is finished, and the
estop still works through the router.

A tracking stream's trajectories (one a cycle, each ending at rest where the stream's deadman
runs out) splice: each names the trajectory it takes over from and when (``after``, ``at``:
:mod:`.trajectory_message`), its first sample that one's sample there. The adapter checks the
junction (the same position; the acceleration across it within the limit), keeps it until
its time comes, and switches there with no jump and no event (a splice refused is said:
``rejected``); one that names another trajectory than the last it has, or comes more than
``MAX_SPLICE_LATE`` after its time (unless it takes over at the other's end, where the arm
rests: it starts from its beginning when it comes), is refused, and the arm goes on to the end of what it has
(at rest). Nothing waits for the service: a stream whose service dies brakes where its
deadman said.

A subclass implements :meth:`execute` (send what is due at time ``t`` of a trajectory; a
``stop`` also while the controller is faulty), :meth:`hold` (bring the arm to rest now with no
plan, never back: the fallback when a stop cannot be planned), :meth:`measure` (the arm's
state, as the hardware reports it or as last commanded) and :meth:`check` (is the controller
well?); it may override :meth:`estimate` (the state with nothing asked of the controller),
:meth:`stop_command` (how to stop from here) and :meth:`unlock`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
import time
import uuid
from abc import ABC, abstractmethod
from collections import OrderedDict, deque
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import orjson
import zenoh

from armd import planning
from armd.errors import ArmdError, BadRequest, ControllerFault, LimitError, PositionUnknown, StartMismatch
from armd.planning import JointState
from armd.robots import Robot
from armd.robots import calibration as robots_calibration
from armd.service.protocol import encode

from .trajectory_message import MAX_BYTES, RATE_TOL, Command, check_size, motion, parse

log = logging.getLogger(__name__)
JSON = zenoh.Encoding.APPLICATION_JSON
START_TOL = 0.02  # [rad] how far a trajectory's first sample may be from where the arm is, at rest
START_LAG = 0.1  # [s] ... plus this long at the arm's present speed (the planner's state was a little old)
SEEN_IDS = 65536  # trajectory ids remembered, so that a replayed one is refused (a stream's 100 a second: 11 min)
MAX_SPLICE_LATE = 0.01  # [s] how long after its time a stream's next trajectory may still take over
SPLICE_TOL = 1e-6  # [rad] how far a splice's first sample may be from the sample it takes over at
INTAKE = 256  # trajectories waiting to be checked, at most (a stream's: one a cycle)
CONTROL_BYTES = 4096  # [bytes] the most an estop or unlock message may carry
UNLOCKS = ("home", "assume_rest")


A = TypeVar("A")


def actuators_of(robot: Robot, kind: type[A], adapter: str) -> list[A]:
    """``robot``'s actuators, every one a ``kind`` (what ``adapter`` drives), else :class:`BadRequest`."""
    acts = robot.actuators.actuators
    if not acts:
        raise BadRequest(
            f"{robot.name} has no [[actuators]] in its robot.toml: the {adapter} adapter needs one per joint (what "
            "drives it and how: docs/robot-format.md); without, the arm is served for IK, plans and --sim only",
            field="robot",
        )
    drives: list[A] = [a for a in acts if isinstance(a, kind)]
    if len(drives) != len(acts):
        what = kind.__name__.lower() + "s"
        raise BadRequest(
            f"{robot.name}'s actuators are not all {what}: the {adapter} adapter drives {what}", field="robot"
        )
    if robot.actuators.linkages and adapter != "SSC-32":
        behind = ", ".join(robot.actuators.names[k] for k in robot.actuators.linkages)
        raise BadRequest(
            f"{robot.name}'s {behind} turns through a four-bar linkage: the SSC-32 adapter drives such servos, "
            f"the {adapter} adapter does not yet (its speed and acceleration settings assume a linear map)",
            field="robot",
        )
    return drives


def state_dir_default() -> Path:
    """Where adapters keep what must outlive them: ``$ARMD_STATE_DIR``, else ``$XDG_STATE_HOME/armd``,
    else ``~/.local/state/armd``."""
    if os.environ.get("ARMD_STATE_DIR"):
        return Path(os.environ["ARMD_STATE_DIR"])
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "armd"


def calibration_file(robot: Robot, state_dir: str | Path | None = None) -> Path:
    """Where ``armd calibrate`` keeps ``robot``'s calibration: beside the adapters' other state
    (``state_dir``, else :func:`state_dir_default`), ``<robot>.calibration.toml``; the arm's
    folder may be the package's own."""
    return Path(state_dir or state_dir_default()) / f"{robot.name}.{robots_calibration.FILE}"


def calibrated(robot: Robot, calibration: str | Path | None = None, state_dir: str | Path | None = None) -> Robot:
    """``robot`` with its calibration (``armd calibrate``) applied: the file ``calibration``, else
    :func:`calibration_file` if there is one, else as it is; checked against its limits
    (:class:`RobotFileError` naming the servo) before any port is opened."""
    path = Path(calibration) if calibration else calibration_file(robot, state_dir)
    if not calibration and not path.exists():
        return robot
    out = robots_calibration.apply(robot, path)
    log.info("%s: calibration from %s", robot.name, path)
    return out


LOOP_PRIORITY = 20  # SCHED_FIFO priority of an adapter's control loop (ros2_control's controller manager uses 50)


def _prioritise_this_thread(name: str, priority: int = LOOP_PRIORITY, what: str = "the control loop") -> None:
    """The control loop ahead of ordinary processes (SCHED_FIFO), where the system permits it
    (root, or CAP_SYS_NICE, or an rtprio limit in /etc/security/limits.conf): on a busy machine,
    a write held up after it was timed reaches the board late. Else as it is, said once."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # (0: this thread, on Linux)
        log.info("%s: %s runs at real-time priority (SCHED_FIFO %d)", name, what, priority)
    except (PermissionError, OSError, AttributeError) as e:
        log.info("%s: %s runs at normal priority (no SCHED_FIFO: %s)", name, what, e)


class Adapter(ABC):
    kind = "adapter"
    splices = True  # whether it follows a tracking stream (its trajectories spliced one into the next)
    tick = 0.005  # [s] the control loop's period; execute() decides what is due
    run_tick = 0.005  # [s] its period while a trajectory runs

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        *,
        prefix: str = "armd",
        state_hz: float = 50.0,
        check_period: float = 0.5,
    ) -> None:
        self.session = session
        self.robot = robot
        self.prefix = prefix.rstrip("/")
        self.id = uuid.uuid4().hex[:12]
        self.state_period = 1.0 / state_hz
        self.check_period = check_period
        base = f"{self.prefix}/{robot.name}"
        self._base = base
        self._lock = threading.Lock()
        self._cmd: Command | None = None
        self._t0 = 0.0
        self._new = False
        self._finished = True
        self._chain: list[Command] = []  # a stream's trajectories waiting for their time, in order
        self._stopped_streams: OrderedDict[str, None] = OrderedDict()  # streams an estop ended: none of theirs runs
        self._wake = threading.Event()  # (the control loop looks again at once: a trajectory came)
        self._stops = 0  # estops so far
        self._intake: queue.Queue[tuple[bytes, int] | None] = queue.Queue(INTAKE)
        self._intake_thread = threading.Thread(
            target=self._take_in, name=f"{self.kind}-intake-{robot.name}", daemon=True
        )
        self.splice_lateness: deque[float] = deque(
            maxlen=4096
        )  # [s] how late a stream's trajectories came (< 0: early)
        self.fault: str | None = None
        self._fault_count = 0  # faulty checks (and errors) since the fault began
        self._fault_since = 0.0  # [s] when it began (monotonic)
        self.homed = True  # whether the arm's position is known (a subclass that can lose it says so)
        self.epoch = 0  # one more each time where the arm is was set anew (the state may jump then)
        self.position_source = "commanded"  # or "measured": what the published state is
        self._seen: OrderedDict[str, None] = OrderedDict()  # ids accepted, newest last
        self._unlock: str | None = None  # an operator's unlock request, for the control loop
        self._latest: JointState = JointState.at_rest(np.array(robot.neutral, dtype=float))
        self._moving = False
        self._state_pub = session.declare_publisher(f"{base}/state", encoding=JSON)
        self._event_pub = session.declare_publisher(
            f"{base}/events", encoding=JSON, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._stop = threading.Event()
        self._token: Any = None
        self._seq = 0  # the state's sequence number: the service ignores one not above the last
        self._subs: list[Any] = []
        self.gripper_opening: float | None = None
        self._thread = threading.Thread(target=self._loop, name=f"{self.kind}-{robot.name}", daemon=True)

    # -- to be provided by the hardware ------------------------------------------------------

    @abstractmethod
    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        """Send what trajectory ``cmd`` asks for at time ``t`` [s]; True once it is complete."""

    @abstractmethod
    def hold(self) -> None:
        """Bring the arm to rest now, with no plan, never back (the fallback when a stop cannot
        be planned)."""

    @abstractmethod
    def measure(self) -> JointState:
        """The arm's state: from the controller where it can tell, else as last commanded."""

    def estimate(self) -> JointState:
        """The arm's state without asking the controller anything (the control loop calls it
        on every pass; the default, :meth:`measure`, for adapters whose measure sends nothing)."""
        return self.measure()

    def check(self) -> None:
        """Raise :class:`ControllerFault` if the controller does not answer (called every check_period)."""
        return None

    def shutdown(self) -> None:
        """Release the hardware (close the port)."""
        return None

    def grip(self, opening: float) -> None:
        """Set the gripper opening in [0, 1] (the default: a simulated gripper just remembers it)."""
        self.gripper_opening = opening

    def stop_command(self, ident: str) -> Command:
        """The stop to run now: jerk-limited, each joint braking as hard as its limits allow,
        from the adapter's own state (a state a hair outside a limit is brought inside first:
        a stop is never refused), sampled at the running trajectory's rate. With the controller
        faulty, from :meth:`estimate` (what the adapter last knew, carried on: nothing asked of
        a controller that may not answer)."""
        with self._lock:
            rate = self._cmd.rate_hz if self._cmd is not None else None
        for _ in range(3):  # planned from a state that is still the arm's: again if planning took a while
            asked = time.monotonic()
            state = self.estimate() if self.fault else self.measure()
            traj = planning.plan_stop(self.robot, state, rate_hz=rate, clamp=True)
            if time.monotonic() - asked < 0.005:
                break
        vel, acc = motion(traj.position, 1.0 / traj.rate_hz)
        return Command(ident, "stop", traj.rate_hz, traj.times, traj.position, vel, acc, traj.commands)

    def spliced(self, before: Command, cmd: Command) -> None:
        """Called on the control loop when a stream's ``cmd`` takes over from ``before`` (at
        ``cmd.at`` of it; ``t`` goes on from there, less ``cmd.at``), before ``cmd`` is first
        executed (the default: nothing; an adapter with a clock of its own moves it)."""
        return None

    def admit(self, cmd: Command) -> None:
        """Raise an :class:`ArmdError` if this controller cannot run ``cmd`` (before anything of
        it is sent; the default: every checked trajectory can run)."""
        return None

    def unlock(self, how: str) -> None:
        """An operator's word that the arm's position is known: ``"home"`` (run the homing
        cycle) or ``"assume_rest"`` (the arm is at its rest pose). Called on the control loop,
        with the arm still. The default: nothing to unlock."""
        raise BadRequest(
            f"the {self.kind} adapter always knows where {self.robot.name} is: nothing to unlock", field="how"
        )

    # -- the Zenoh side ----------------------------------------------------------------------

    def activate(self) -> None:
        """Start: subscribe to trajectories, the gripper, the estop and unlock keys, and declare
        the liveliness token (call when the hardware is ready)."""
        for key, callback in (
            ("trajectory", self._on_trajectory),
            ("gripper", self._on_gripper),
            ("estop", self._on_estop),
            ("unlock", self._on_unlock),
        ):
            self._subs.append(self.session.declare_subscriber(f"{self._base}/{key}", callback))
        self.stop_command("warm-up")  # (a first stop compiles the planner's code: seconds, not now but here)
        self._token = self.session.liveliness().declare_token(f"{self._base}/adapter/{self.id}")
        if self._refresh():
            self._publish_state()  # where the arm is, at once (the service trusts states of live tokens only)
        self._intake_thread.start()
        self._thread.start()

    def event(self, event: str, **fields: Any) -> None:
        try:
            self._event_pub.put(
                encode({"event": event, "adapter": self.id, "kind": self.kind, "time": time.time(), **fields})
            )
        except zenoh.ZError:  # the session is gone (the process is ending)
            log.debug("event %s not published", event, exc_info=True)

    def _on_gripper(self, sample: zenoh.Sample) -> None:
        try:
            msg = _control_message(sample)
            opening = msg["opening"]
            if isinstance(opening, bool) or not isinstance(opening, (int, float)) or not 0.0 <= opening <= 1.0:
                raise ValueError(f"opening must be a number in [0, 1], got {opening!r}")
            self.grip(float(opening))
            self.event("gripper", id=msg.get("id"), opening=float(opening))
        except (ValueError, KeyError, TypeError, ArmdError) as e:
            self.event("rejected", reason=f"gripper command: {e}")

    def _on_trajectory(self, sample: zenoh.Sample) -> None:
        """A trajectory, handed to the intake thread (:meth:`_take_in`): Zenoh's thread only copies
        it. Parsing and checking one (a millisecond or two of a stream's, a hundred a second) holds
        Python's lock; done on Zenoh's thread, of ordinary priority, a busy machine preempts it
        holding the lock, and the control loop, however urgent, waits: the SSC-32's lines then came
        65 ms late, the board stopped dead at speed (130x its acceleration limit, measured beside two
        busy processes). The intake thread runs at the loop's real-time priority, one below. (Zenoh's
        thread is left as it is: in `armd serve --sim` it also answers the service's requests, which
        must never run ahead of every process on the machine.)"""
        try:
            check_size(len(sample.payload))  # (before it is copied)
        except ArmdError as e:
            log.warning("%s: trajectory rejected: %s", self.robot.name, e.message)
            self.event("rejected", reason=e.message, error=e.to_dict())
            return
        payload = sample.payload.to_bytes()
        with self._lock:
            stops = self._stops
        try:
            self._intake.put_nowait((payload, stops))
        except queue.Full:
            self.event(
                "rejected",
                **_claimed_id(payload),
                reason=f"{INTAKE} trajectories wait to be checked already: this one is dropped",
            )

    def _take_in(self) -> None:
        """The intake thread: each trajectory checked and taken, in the order they came."""
        _prioritise_this_thread(self.robot.name, LOOP_PRIORITY - 1, "the trajectories' intake")
        while True:
            item = self._intake.get()
            if item is None:
                return
            try:
                self._take(*item)
            except Exception:  # a bug: never the end of the intake
                log.exception("%s: a trajectory could not be taken", self.robot.name)

    def _take(self, payload: bytes, stops: int) -> None:
        """Check ``payload`` and run it, unless an estop came after it arrived (a stop is never
        undone by what was on its way before it)."""
        try:
            cmd = parse(self.robot, payload)
        except ArmdError as e:
            log.warning("%s: trajectory rejected: %s", self.robot.name, e.message)
            self.event("rejected", **_claimed_id(payload), reason=e.message, error=e.to_dict())
            return
        if cmd.kind == "stop":  # a stop is never refused, and always from the adapter's own state
            self.emergency_stop(cmd.id, "stop trajectory")
            return
        try:
            if self.fault:
                raise ControllerFault(f"the controller is faulty: {self.fault}")
            self.admit(cmd)
            if not self.homed:
                raise PositionUnknown(
                    f"{self.robot.name}'s position is unknown (the controller lost it): home it "
                    "or confirm its rest pose (armd unlock) before moving it",
                    robot=self.robot.name,
                )
            if cmd.track is not None:
                if not self.splices:
                    raise BadRequest(f"the {self.kind} adapter does not follow a tracking stream", field="track")
                if cmd.track in self._stopped_streams:
                    raise BadRequest(f"tracking stream {cmd.track!r} was stopped here: a new one starts", field="track")
                if cmd.after is not None and self._splice(cmd, stops):
                    return
                with self._lock:
                    if self._cmd is not None and not self._finished:
                        raise BadRequest(
                            f"{self.robot.name} is moving ({self._cmd.id}): a tracking stream starts from rest",
                            field="splice",
                        )
            self._check_start(cmd)
            with self._lock:
                if self._stops != stops:
                    raise BadRequest(f"an estop came after trajectory {cmd.id}: it does not run", field="id")
                if cmd.id in self._seen:
                    raise BadRequest(f"trajectory {cmd.id} was accepted before: an id runs at most once", field="id")
                self._remember(cmd.id)
        except ArmdError as e:
            log.warning("%s: trajectory %s rejected: %s", self.robot.name, cmd.id, e.message)
            self.event("rejected", id=cmd.id, reason=e.message, error=e.to_dict())
            return
        self._install(cmd)

    def _splice(self, cmd: Command, stops: int) -> bool:
        """Queue a stream's ``cmd`` to take over from the trajectory it names, at its time
        (True); False if nothing runs (then it starts as any trajectory does, where the arm
        is); else :class:`BadRequest` saying why not."""
        with self._lock:
            if self._stops != stops:
                raise BadRequest(f"an estop came after trajectory {cmd.id}: it does not run", field="id")
            if self._finished:  # (what was left of a stream that ended: an abort, a fault's stop)
                self._chain.clear()
            before = self._chain[-1] if self._chain else None
            if before is None and self._cmd is not None and not self._finished:
                before = self._cmd
            if before is None:
                return False
            if before.id != cmd.after:
                raise BadRequest(
                    f"trajectory {cmd.id} takes over from {cmd.after}, but {before.id} is the last one here "
                    "(a stop, a move, or a stream's trajectory that was refused came between)",
                    field="splice.after",
                )
            k = round(cmd.at * cmd.rate_hz)
            if before.rate_hz != cmd.rate_hz or k > len(before.times) - 1:
                raise BadRequest(
                    f"trajectory {cmd.id} takes over at sample {k} of {before.id}: it has "
                    f"{len(before.times)} at {before.rate_hz:g} Hz, this one {cmd.rate_hz:g} Hz",
                    field="splice.at",
                )
            off = np.abs(cmd.position[0] - before.position[k])
            if np.any(off > SPLICE_TOL):
                j = int(np.argmax(off))
                raise StartMismatch(
                    f"trajectory {cmd.id} starts {off[j]:.3g} rad from {before.id}'s sample at "
                    f"{cmd.at:.4f} s on {self.robot.joint_names[j]}",
                    field="position",
                    joint=self.robot.joint_names[j],
                )
            if k > 0 and len(cmd.times) > 1:  # the acceleration across the junction
                acc = (cmd.position[1] - 2.0 * cmd.position[0] + before.position[k - 1]) * cmd.rate_hz**2
                limit = self.robot.limits.acceleration
                over = np.abs(acc) > limit * (1 + RATE_TOL) + 1e-9
                if np.any(over):
                    j = int(np.argmax(np.abs(acc) / limit))
                    raise LimitError(
                        f"joint {self.robot.joint_names[j]!r} changes speed at {acc[j]:.6g} rad/s^2 where "
                        f"trajectory {cmd.id} takes over, over its acceleration limit {limit[j]:.6g} rad/s^2",
                        name=self.robot.joint_names[j],
                        value=float(acc[j]),
                        bounds=(-float(limit[j]), float(limit[j])),
                        kind="acceleration",
                    )
            due = self._t0 + sum(c.at for c in self._chain) + cmd.at
            late = time.monotonic() - due
            self.splice_lateness.append(late)
            if late > MAX_SPLICE_LATE and k < len(before.times) - 1:  # (at its end, at rest: it starts on arrival)
                raise BadRequest(
                    f"trajectory {cmd.id} came {late * 1e3:.0f} ms after its time to take over from "
                    f"{cmd.after} (at most {MAX_SPLICE_LATE * 1e3:.0f} ms): the arm goes on to that one's end",
                    field="splice.at",
                    late=late,
                )
            if cmd.id in self._seen:
                raise BadRequest(f"trajectory {cmd.id} was accepted before: an id runs at most once", field="id")
            self._remember(cmd.id)
            self._chain.append(cmd)
        self._wake.set()
        return True

    def _remember(self, ident: str) -> None:
        self._seen[ident] = None
        while len(self._seen) > SEEN_IDS:
            self._seen.popitem(last=False)

    def _check_start(self, cmd: Command) -> None:
        """The first sample must be where the arm is (within ``START_TOL``, plus ``START_LAG``
        at its present speed): a trajectory planned from elsewhere would make the arm jump."""
        here = self._latest
        off = np.abs(cmd.position[0] - here.position)
        tol = START_TOL + np.abs(here.velocity) * START_LAG
        if np.any(off > tol):
            j = int(np.argmax(off - tol))
            name = self.robot.joint_names[j]
            raise StartMismatch(
                f"the trajectory starts {off[j]:.4f} rad from where {name} is "
                f"({here.position[j]:.4f} rad; at most {tol[j]:.4f} here): planned from another "
                "state",
                field="position",
                joint=name,
                state=here.to_dict(),
            )

    def _install(self, cmd: Command, reason: str | None = None) -> None:
        """Make ``cmd`` the running trajectory (the control loop starts it on its next pass);
        the one it replaces is aborted, for ``reason`` (default: replaced)."""
        with self._lock:
            if self._cmd is not None and not self._finished:
                self.event("aborted", id=self._cmd.id, reason=reason or f"replaced by {cmd.id}")
            # said before the loop can see it (under the lock): "accepted" always precedes "started"
            self.event("accepted", id=cmd.id, trajectory=cmd.kind, duration=cmd.duration)
            self._cmd = cmd
            self._chain.clear()
            self._t0 = time.monotonic()
            self._new = True
            self._finished = False
        self._wake.set()

    def _on_estop(self, sample: zenoh.Sample) -> None:
        """Any put stops the arm: a malformed message too (its id is made up)."""
        ident, reason = uuid.uuid4().hex, "estop"
        try:
            msg = _control_message(sample)
            if isinstance(msg.get("id"), str) and 0 < len(msg["id"]) <= 64:
                ident = msg["id"]
            if isinstance(msg.get("by"), str):
                reason = f"estop by {msg['by'][:64]}"
        except Exception:  # (whatever the payload holds, or fails to: the arm stops)
            pass
        self.emergency_stop(ident, reason)

    def emergency_stop(self, ident: str, reason: str) -> None:
        """Brake from the adapter's own state at once (:meth:`stop_command`); never refused, the
        controller faulty or not (a stop runs under a fault). If the stop cannot be planned,
        :meth:`hold`."""
        log.info("%s: %s (%s)", self.robot.name, reason, ident)
        with self._lock:
            self._stops += 1  # (a trajectory that came before it and waits to be checked: never run)
        with self._lock:  # the stream it stops (running, or the last one: at rest) is over here
            if self._cmd is not None and self._cmd.track is not None:
                self._stopped_streams[self._cmd.track] = None
                while len(self._stopped_streams) > SEEN_IDS:
                    self._stopped_streams.popitem(last=False)
        try:
            cmd: Command | None = self.stop_command(ident)
        except Exception as e:  # a stop must happen whatever: hold
            log.exception("%s: the stop could not be planned: holding", self.robot.name)
            self.event("fault", reason=f"stop not planned ({type(e).__name__}: {e}): held")
            cmd = None
        if cmd is None:
            with self._lock:
                if self._cmd is not None and not self._finished:
                    self.event("aborted", id=self._cmd.id, reason=reason)
                self._finished = True
                self._chain.clear()
            self.event("accepted", id=ident, trajectory="stop", duration=0.0, reason=reason)
            try:
                self.hold()
            except Exception:  # the controller may be gone
                log.debug("hold failed", exc_info=True)
            self.event("done", id=ident)
            return
        with self._lock:
            self._remember(ident)
        self._install(cmd, reason)

    def _on_unlock(self, sample: zenoh.Sample) -> None:
        try:
            msg = _control_message(sample)
            how = msg.get("how")
            if how not in UNLOCKS:
                raise BadRequest(f"unlock needs 'how': one of {', '.join(UNLOCKS)}", field="how")
            with self._lock:
                if self._cmd is not None and not self._finished:
                    raise BadRequest("the arm is moving: stop it before unlocking", field="how")
                self._unlock = how
        except ArmdError as e:
            self.event("rejected", reason=f"unlock: {e.message}", error=e.to_dict())

    def _loop(self) -> None:
        _prioritise_this_thread(self.robot.name)
        next_state = next_check = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            cmd, finished = None, True
            try:
                with self._lock:  # an operator's unlock, taken before the check: it is what ends a
                    # fault whose check fails until someone acts (GRBL's limit alarm wants a reset)
                    unlock, self._unlock = (self._unlock, None) if self._finished else (None, self._unlock)
                if unlock is not None:
                    self._do_unlock(unlock)
                if now >= next_check:
                    next_check = now + self.check_period
                    self.check()
                    if self.fault:
                        self._recovered()
                switched: list[tuple[Command, Command]] = []
                with self._lock:  # (after the check, which may have ended or replaced the trajectory)
                    while self._chain and not self._finished and time.monotonic() >= self._t0 + self._chain[0].at:
                        nxt = self._chain.pop(0)  # a stream's next trajectory, its time come
                        due = self._t0 + nxt.at
                        if self._cmd is not None:
                            switched.append((self._cmd, nxt))
                            if nxt.at >= self._cmd.duration - 1e-9:  # (taking over where it rests: from its start)
                                due = max(due, time.monotonic())
                        self._cmd, self._t0 = nxt, due
                    cmd, t0, first, finished = self._cmd, self._t0, self._new, self._finished
                    self._new = False
                for before, nxt in switched:
                    self.spliced(before, nxt)
                # (a stop runs under a fault too: the one that brakes the arm after it)
                if cmd is not None and not finished and (not self.fault or cmd.kind == "stop"):
                    if first:
                        self.event("started", id=cmd.id)
                    if self.execute(cmd, time.monotonic() - t0, first):  # (now: the check may have taken a while)
                        with self._lock:
                            if self._cmd is cmd:
                                self._finished = True
                        self.event("done", id=cmd.id)
                        self.finished(cmd)
            except ControllerFault as e:
                self._faulted(e.message, cmd)
            except Exception as e:  # a bug must not leave the arm moving unattended
                reason = f"adapter error: {type(e).__name__}: {e}"
                if reason != self.fault:  # (its traceback once, not at every pass)
                    log.exception("%s adapter error", self.kind)
                self._faulted(reason, cmd)
            if now >= next_state:  # (on the state's own beat: a slow pass, a bus waiting for a reply, costs no rate)
                next_state = max(next_state + self.state_period, now)
                if self._refresh():
                    self._publish_state()
            else:  # (every pass: what a trajectory's start is checked against)
                self._refresh(ask=False)
            wait = self.run_tick if cmd is not None and not finished else self.tick
            with self._lock:
                if self._chain and not self._finished:  # (a stream's next trajectory: taken over on time)
                    wait = min(wait, max(self._t0 + self._chain[0].at - time.monotonic(), 0.0))
            self._wake.wait(wait)
            self._wake.clear()

    def finished(self, cmd: Command) -> None:
        """Called on the control loop when ``cmd`` is complete (the default: nothing)."""
        return None

    def _do_unlock(self, how: str) -> None:
        try:
            self.unlock(how)
        except ArmdError as e:
            self.event("rejected", reason=f"unlock: {e.message}", error=e.to_dict())
            if isinstance(e, ControllerFault):
                raise
            return
        self.new_epoch()
        self.event("unlocked", how=how)

    def new_epoch(self) -> None:
        """Where the arm is was set anew (an unlock, a homing, a controller set up again): the
        state's ``epoch`` goes up, and the state is published at once, before anything is said of
        it, so the service believes the new position (which may jump) with no wait."""
        self.epoch += 1
        if self._refresh():
            self._publish_state()

    def _faulted(self, reason: str, cmd: Command | None) -> None:
        """The controller is faulty for ``reason``: said once (the event ``fault``, a line in
        the log; the same reason again is only counted), the token withdrawn (``move`` answers
        ``no_adapter``), and an arm in motion braked to rest from the adapter's own state, as
        ``stop`` does (:meth:`_brake`): never held where it was last seen, which a joint at
        speed has passed already."""
        self._fault_count += 1
        if self.fault == reason:
            return
        now = time.monotonic()
        first = self.fault is None
        if first:
            self._fault_since, self._fault_count = now, 1
        self.fault = reason
        log.error("%s: %s", self.robot.name, reason)
        with self._lock:
            running = self._cmd is not None and not self._finished
        self.event("fault", reason=reason, count=self._fault_count)
        if first and self._token is not None:  # no longer able to drive: move must say no_adapter
            self._token.undeclare()
            self._token = None
        if running:  # (an arm at rest: nothing to brake; the controller holds it)
            self._brake(reason)

    def _brake(self, reason: str) -> None:
        """The running trajectory (if any) replaced by a stop planned from the adapter's own
        state, run under the fault; :meth:`hold` if it cannot be planned."""
        ident = f"fault-{uuid.uuid4().hex[:12]}"
        try:
            stop = self.stop_command(ident)
        except Exception as e:  # (a stop that cannot be planned: hold, and say so)
            log.exception("%s: the stop after a fault could not be planned: holding", self.robot.name)
            with self._lock:
                running = self._cmd is not None and not self._finished
                self._finished = True
                self._chain.clear()
            if running and self._cmd is not None:
                self.event("aborted", id=self._cmd.id, reason=reason)
            self.event("fault", reason=f"stop not planned ({type(e).__name__}: {e}): held", count=self._fault_count)
            try:
                self.hold()
            except Exception:  # the controller may be gone
                log.debug("hold failed", exc_info=True)
            return
        with self._lock:
            self._remember(ident)
        self._install(stop, reason)

    def _recovered(self) -> None:
        now = time.monotonic()
        log.info(
            "%s: the controller answers again (%d faulty checks in %.1f s)",
            self.robot.name,
            self._fault_count,
            now - self._fault_since,
        )
        self.fault = None
        self.event("recovered", count=self._fault_count, duration=now - self._fault_since)
        self._fault_count = 0
        if self._token is None:
            self._token = self.session.liveliness().declare_token(f"{self._base}/adapter/{self.id}")

    def _refresh(self, ask: bool = True) -> bool:
        """Where the arm is now (``_latest``; at rest unless a trajectory runs): from
        :meth:`measure` (``ask``: at the state rate, what the controller is asked as before),
        else from :meth:`estimate` (every pass, no traffic to the controller). False if the
        controller could not say."""
        with self._lock:
            cmd, finished = self._cmd, self._finished
        try:
            s = self.measure() if ask else self.estimate()
        except Exception:  # the controller may be gone: the fault path reports it, the state goes on
            log.debug("measure failed", exc_info=True)
            try:
                s = self.estimate()
            except Exception:
                return False
        self._moving = cmd is not None and not finished
        self._latest = s if self._moving else JointState.at_rest(s.position)
        return True

    def _publish_state(self) -> None:
        with self._lock:
            cmd = self._cmd
        s, moving = self._latest, self._moving
        message = encode(
            {
                "robot": self.robot.name,
                "adapter": self.id,
                "kind": self.kind,
                "position": s.position.tolist(),
                "velocity": s.velocity.tolist(),
                "acceleration": s.acceleration.tolist(),
                "moving": moving,
                "trajectory": None if cmd is None else cmd.id,
                "fault": self.fault,
                "homed": self.homed,
                "epoch": self.epoch,
                "source": self.position_source,
                "time": time.time(),
                "seq": self._seq,
            }
        )
        self._seq += 1
        try:
            self._state_pub.put(message)
        except zenoh.ZError:  # the session is gone: nobody to tell
            self._stop.set()

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._intake_thread.is_alive():
            with contextlib.suppress(queue.Full):
                self._intake.put_nowait(None)
            self._intake_thread.join(timeout=2.0)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for entity in (self._token, *self._subs, self._state_pub, self._event_pub):
            if entity is None:
                continue
            try:
                entity.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self.shutdown()


def _claimed_id(payload: bytes) -> dict[str, str]:
    """``{"id": ...}`` of a refused trajectory message, if it names one (so that whoever sent it
    hears the refusal), else nothing."""
    if len(payload) > MAX_BYTES:
        return {}
    try:
        ident = orjson.loads(payload).get("id")
    except (orjson.JSONDecodeError, AttributeError):
        return {}
    return {"id": ident} if isinstance(ident, str) and 0 < len(ident) <= 64 else {}


def _control_message(sample: zenoh.Sample) -> dict[str, Any]:
    """The JSON object of an estop, gripper or unlock put, or :class:`BadRequest` saying why
    not: over ``CONTROL_BYTES`` (not copied), not JSON (orjson: any nesting is an error, never a
    recursion), not an object."""
    size = len(sample.payload)
    if size > CONTROL_BYTES:
        raise BadRequest(f"the message has {size} bytes, more than {CONTROL_BYTES}", field="payload")
    try:
        msg = orjson.loads(sample.payload.to_bytes())
    except orjson.JSONDecodeError as e:
        raise BadRequest(f"not JSON ({e})", field="payload") from None
    if not isinstance(msg, dict):
        raise BadRequest(f"not a JSON object (a {type(msg).__name__})", field="payload")
    return msg
