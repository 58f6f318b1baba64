"""The SSC-32 adapter: servo arms on a Lynxmotion SSC-32 (seeds 000 and 003).

``armd adapter ssc32 ROBOT --port /dev/ttyUSB0 [--baud 115200]``. The port may be any
pyserial URL (``/dev/ttyUSB0``, a pseudo-terminal, ``socket://host:port``).

It streams a trajectory as timed group moves, one per sample: ``#<ch>P<pw>...T<ms>\\r``
with every servo channel of the arm's actuator map (the SG5-UT's mirrored shoulder pair
included) and ``T`` = one sample period, so the board interpolates between samples and the
servos move smoothly. ``VER`` is read at start (no answer: the adapter does not start);
``Q`` every ``check_period`` tells the board still answers (no answer: a fault, reported,
and the adapter stops driving until it answers again: nothing hangs). The gripper, a
separate channel, opens and closes on ``<prefix>/<robot>/gripper`` (the service's ``gripper`` verb).

Hobby servos have no position feedback: the state it reports is what it last commanded,
mapped back through the actuator map (``QP`` only echoes the board's own interpolation).
At start it brings the arm to the neutral pose slowly (``home_time``), so that the state it
reports is true from then on.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import serial
import zenoh

from planning import JointState
from robots import BadRequest, Robot, Servo

from .adapter import ControllerFault, SerialAdapter, actuators_of
from .trajectory_message import Command

log = logging.getLogger("armd.ssc32")


class SSC32Adapter(SerialAdapter):
    kind = "ssc32"

    def __init__(self, session: zenoh.Session, robot: Robot, port: str, *, baud: int = 115200,
                 prefix: str = "armd", state_hz: float = 50.0, timeout: float = 0.25, home_time: float = 2.0,
                 check_period: float = 0.5) -> None:
        self.channels = [a.channel for a in actuators_of(robot, Servo, "SSC-32")]
        super().__init__(session, robot, port, baud=baud, timeout=timeout, write_timeout=timeout, prefix=prefix,
                         state_hz=state_hz, check_period=check_period)
        self.version = self._ask(b"VER\r", until=b"\r").decode(errors="replace").strip()
        if not self.version:
            self.serial.close()
            raise ControllerFault(f"no SSC-32 answers on {port} (VER got no reply)")
        log.info("%s on %s: %s", robot.name, port, self.version)
        self._q = np.array(robot.neutral, dtype=float)
        self._v = np.zeros(robot.nq)
        self._a = np.zeros(robot.nq)
        self._sent = -1
        self._send(robot.actuators.commands(self._q), int(home_time * 1000))
        time.sleep(home_time)
        self.activate()

    # -- the wire ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        try:
            with self._io:
                self.serial.write(data)
        except (serial.SerialException, serial.SerialTimeoutException) as e:
            raise ControllerFault(f"SSC-32 on {self.port}: write failed: {e}") from None

    def _ask(self, request: bytes, *, until: bytes | None = None, size: int = 1) -> bytes:
        try:
            with self._io:
                self.serial.reset_input_buffer()
                self.serial.write(request)
                if until is not None:
                    return bytes(self.serial.read_until(until))
                return bytes(self.serial.read(size))
        except (serial.SerialException, serial.SerialTimeoutException) as e:
            raise ControllerFault(f"SSC-32 on {self.port}: {e}") from None

    def _send(self, pulses: np.ndarray, duration_ms: int | None) -> None:
        line = "".join(f"#{ch}P{int(pw)}" for ch, pw in zip(self.channels, pulses.tolist(), strict=True))
        if duration_ms is not None:
            line += f"T{max(duration_ms, 1)}"
        self._write((line + "\r").encode())

    # -- the Adapter hooks ----------------------------------------------------------------------

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        if first:
            self._sent = -1
        last = len(cmd.times) - 1
        k = min(int(t * cmd.rate_hz), last)
        if k > self._sent:
            # every sample due, the newest one sent as the group move toward it (one period long)
            self._send(cmd.commands[k], round(1000.0 / cmd.rate_hz))
            self._sent = k
            self._q, self._v, self._a = cmd.position[k].copy(), cmd.velocity[k].copy(), cmd.acceleration[k].copy()
        return k >= last and t >= cmd.duration + 1.0 / cmd.rate_hz

    def hold(self) -> None:
        """Stop sending: the board completes the current one-period move and holds there."""
        self._v = np.zeros(self.robot.nq)
        self._a = np.zeros(self.robot.nq)

    def measure(self) -> JointState:
        return JointState(self._q.copy(), self._v.copy(), self._a.copy())

    def check(self) -> None:
        reply = self._ask(b"Q\r")
        if reply not in (b".", b"+"):
            raise ControllerFault(f"SSC-32 on {self.port} does not answer (Q got {reply!r})")

    def grip(self, opening: float) -> None:
        """Open (1) or close (0) the gripper, or anything between: its own channel, over 0.5 s."""
        g = self.robot.gripper
        if g is None:
            raise BadRequest(f"{self.robot.name} has no gripper", field="gripper")
        self._write(f"#{g.channel}P{g.pulse(opening)}T500\r".encode())
        self.gripper_opening = opening

    def shutdown(self) -> None:
        try:
            self.serial.close()
        except Exception:  # already gone
            log.debug("close failed", exc_info=True)
