"""What every adapter daemon does on the Zenoh side; the hardware part is a subclass's.

An adapter holds a liveliness token ``<prefix>/<robot>/adapter/<id>`` while it can drive
its arm, takes trajectories from ``<prefix>/<robot>/trajectory`` (each re-checked against
every limit and actuator range: one bad sample rejects the whole trajectory, and nothing
of it reaches the wire), lets a newer trajectory replace the running one, publishes
``<prefix>/<robot>/state`` at ``state_hz`` and ``<prefix>/<robot>/events`` (accepted,
started, done, rejected, aborted, fault). A controller that stops answering is a fault:
the adapter stops executing, reports it, and withdraws its token (so ``move`` answers
``no_adapter``) until it answers again.

A subclass implements :meth:`execute` (send what is due at time ``t`` of a trajectory),
:meth:`hold` (stop now), :meth:`measure` (the arm's state, as the hardware reports it or as
last commanded) and :meth:`check` (is the controller alive?).
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from abc import ABC, abstractmethod
from typing import Any, TypeVar

import numpy as np
import serial
import zenoh

from planning import JointState
from robots import ArmdError, BadRequest, Robot
from service.protocol import encode

from .trajectory_message import Command, parse

log = logging.getLogger("armd.adapter")
JSON = zenoh.Encoding.APPLICATION_JSON


class ControllerFault(ArmdError):
    """The controller stopped answering, or reported an error or alarm."""

    code = "fault"


def open_port(port: str, baud: int, timeout: float, write_timeout: float) -> serial.SerialBase:
    """A serial port or pyserial URL, opened; :class:`ControllerFault` naming it if it cannot be."""
    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=timeout, write_timeout=write_timeout)
    except (serial.SerialException, ValueError) as e:
        raise ControllerFault(f"cannot open {port}: {e}") from None


A = TypeVar("A")


def actuators_of(robot: Robot, kind: type[A], adapter: str) -> list[A]:
    """``robot``'s actuators, every one a ``kind`` (what ``adapter`` drives), else :class:`BadRequest`."""
    acts = robot.actuators.actuators
    drives: list[A] = [a for a in acts if isinstance(a, kind)]
    if len(drives) != len(acts):
        what = kind.__name__.lower() + "s"
        raise BadRequest(f"{robot.name}'s actuators are not all {what}: the {adapter} adapter drives {what}",
                         field="robot")
    return drives


class Adapter(ABC):
    kind = "adapter"
    tick = 0.005  # [s] the control loop's period; execute() decides what is due

    def __init__(self, session: zenoh.Session, robot: Robot, *, prefix: str = "armd", state_hz: float = 50.0,
                 check_period: float = 0.5) -> None:
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
        self.fault: str | None = None
        self._state_pub = session.declare_publisher(f"{base}/state", encoding=JSON)
        self._event_pub = session.declare_publisher(f"{base}/events", encoding=JSON,
                                                    congestion_control=zenoh.CongestionControl.BLOCK)
        self._stop = threading.Event()
        self._token: Any = None
        self._sub: Any = None
        self._grip_sub: Any = None
        self.gripper_opening: float | None = None
        self._thread = threading.Thread(target=self._loop, name=f"{self.kind}-{robot.name}", daemon=True)

    # -- to be provided by the hardware ------------------------------------------------------

    @abstractmethod
    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        """Send what trajectory ``cmd`` asks for at time ``t`` [s]; True once it is complete."""

    @abstractmethod
    def hold(self) -> None:
        """Stop the arm where it is, now."""

    @abstractmethod
    def measure(self) -> JointState:
        """The arm's state: from the controller where it can tell, else as last commanded."""

    def check(self) -> None:
        """Raise :class:`ControllerFault` if the controller does not answer (called every check_period)."""
        return None

    def shutdown(self) -> None:
        """Release the hardware (close the port)."""
        return None

    def grip(self, opening: float) -> None:
        """Set the gripper opening in [0, 1] (the default: a simulated gripper just remembers it)."""
        self.gripper_opening = opening

    # -- the Zenoh side ----------------------------------------------------------------------

    def activate(self) -> None:
        """Start: subscribe to trajectories and declare the liveliness token (call when the
        hardware is ready)."""
        self._sub = self.session.declare_subscriber(f"{self._base}/trajectory", self._on_trajectory)
        self._grip_sub = self.session.declare_subscriber(f"{self._base}/gripper", self._on_gripper)
        self._publish_state()  # where the arm is, before anyone can plan for it
        self._token = self.session.liveliness().declare_token(f"{self._base}/adapter/{self.id}")
        self._thread.start()

    def event(self, event: str, **fields: Any) -> None:
        try:
            self._event_pub.put(encode({"event": event, "adapter": self.id, "kind": self.kind, "time": time.time(),
                                        **fields}))
        except zenoh.ZError:  # the session is gone (the process is ending)
            log.debug("event %s not published", event, exc_info=True)

    def _on_gripper(self, sample: zenoh.Sample) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
            opening = float(msg["opening"])
            if not 0.0 <= opening <= 1.0:
                raise ValueError(f"opening {opening} outside [0, 1]")
            self.grip(opening)
            self.event("gripper", id=msg.get("id"), opening=opening)
        except (ValueError, KeyError, TypeError, ArmdError) as e:
            self.event("rejected", reason=f"gripper command: {e}")

    def _on_trajectory(self, sample: zenoh.Sample) -> None:
        try:
            if self.fault:
                raise ControllerFault(f"the controller is faulty: {self.fault}")
            cmd = parse(self.robot, sample.payload.to_bytes())
        except ArmdError as e:
            log.warning("%s: trajectory rejected: %s", self.robot.name, e.message)
            self.event("rejected", reason=e.message, error=e.to_dict())
            return
        with self._lock:
            if self._cmd is not None and not self._finished:
                self.event("aborted", id=self._cmd.id, reason=f"replaced by {cmd.id}")
            # said before the loop can see it (under the lock): "accepted" always precedes "started"
            self.event("accepted", id=cmd.id, trajectory=cmd.kind, duration=cmd.duration)
            self._cmd = cmd
            self._t0 = time.monotonic()
            self._new = True
            self._finished = False

    def _loop(self) -> None:
        next_state = next_check = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                cmd, t0, first, finished = self._cmd, self._t0, self._new, self._finished
                self._new = False
            try:
                if now >= next_check:
                    next_check = now + self.check_period
                    self.check()
                    if self.fault:
                        self._recovered()
                if cmd is not None and not finished and not self.fault:
                    if first:
                        self.event("started", id=cmd.id)
                    if self.execute(cmd, now - t0, first):
                        with self._lock:
                            if self._cmd is cmd:
                                self._finished = True
                        self.event("done", id=cmd.id)
            except ControllerFault as e:
                self._faulted(e.message, cmd)
            except Exception as e:  # a bug must not leave the arm moving unattended
                log.exception("%s adapter error", self.kind)
                self._faulted(f"adapter error: {type(e).__name__}: {e}", cmd)
            if now >= next_state:
                next_state = now + self.state_period
                self._publish_state()
            self._stop.wait(self.tick)

    def _faulted(self, reason: str, cmd: Command | None) -> None:
        if self.fault == reason:
            return
        first = self.fault is None
        self.fault = reason
        log.error("%s: %s", self.robot.name, reason)
        with self._lock:
            running = self._cmd is not None and not self._finished
            self._finished = True
        if running and cmd is not None:
            self.event("aborted", id=cmd.id, reason=reason)
        self.event("fault", reason=reason)
        if first and self._token is not None:  # no longer able to drive: move must say no_adapter
            self._token.undeclare()
            self._token = None
        try:
            self.hold()
        except Exception:  # the controller may be gone
            log.debug("hold failed", exc_info=True)

    def _recovered(self) -> None:
        log.info("%s: controller answers again", self.robot.name)
        self.fault = None
        self.event("recovered")
        if self._token is None:
            self._token = self.session.liveliness().declare_token(f"{self._base}/adapter/{self.id}")

    def _publish_state(self) -> None:
        with self._lock:
            cmd, finished = self._cmd, self._finished
        try:
            s = self.measure()
        except Exception:  # the controller may be gone: the fault path reports it
            log.debug("measure failed", exc_info=True)
            return
        moving = cmd is not None and not finished and not self.fault
        zeros = np.zeros(self.robot.nq)
        message = encode({
            "robot": self.robot.name, "adapter": self.id, "kind": self.kind,
            "position": s.position.tolist(),
            "velocity": (s.velocity if moving else zeros).tolist(),
            "acceleration": (s.acceleration if moving else zeros).tolist(),
            "moving": moving, "trajectory": None if cmd is None else cmd.id, "fault": self.fault,
            "time": time.time()})
        try:
            self._state_pub.put(message)
        except zenoh.ZError:  # the session is gone: nobody to tell
            self._stop.set()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for entity in (self._token, self._sub, self._grip_sub, self._state_pub, self._event_pub):
            if entity is None:
                continue
            try:
                entity.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self.shutdown()


class SerialAdapter(Adapter):
    """An adapter whose controller is on a serial port (or a pyserial URL): the port, opened
    (:func:`open_port`), and the lock its users share (the control loop, gripper requests)."""

    def __init__(self, session: zenoh.Session, robot: Robot, port: str, *, baud: int, timeout: float,
                 write_timeout: float, prefix: str = "armd", state_hz: float = 50.0, check_period: float = 0.5) -> None:
        self.port = port
        self._io = threading.Lock()
        self.serial = open_port(port, baud, timeout, write_timeout)
        super().__init__(session, robot, prefix=prefix, state_hz=state_hz, check_period=check_period)
