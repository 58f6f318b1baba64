"""The GRBL adapter: stepper arms on an Arduino running GRBL 1.1 (seed 002's arm).

``armd adapter grbl ROBOT --port /dev/ttyACM0 [--baud 115200]``. The port may be any
pyserial URL.

Joint i's stepper is GRBL axis X, Y or Z (the actuator map's ``axis``), in degrees of the
actuator angle (GRBL's "mm" are degrees here). On connect the adapter waits for GRBL's
welcome (or resets it), sets ``$100..$102`` (steps per degree, from the micro-step
settings), ``$110..$112`` and ``$120..$122`` (rates and accelerations a little above the
joints' limits, so GRBL's own planner never changes the timing armd planned), checks each
``ok``, and reads the machine position. GRBL's machine zero is the joints' zero: start GRBL
with the arm at q = 0 (or home it there).

A trajectory is streamed as one ``G1`` segment per sample, each to that sample's position
in whole micro-steps at the feed rate that takes one period (samples with no whole step to
make are folded into the next segment), with character-counting flow
control: the bytes of unacknowledged lines never exceed GRBL's 128-byte receive buffer.
``error:N`` or ``ALARM:N`` aborts the trajectory (feed hold, then a reset to flush GRBL's
buffer) and is reported. A newer trajectory (a stop, say) replaces the running one the same
way: feed hold ``!``, wait for the hold to complete, soft reset (position kept), stream the
new one from where the arm is. ``?`` status reports give the position the state reports.
"""

from __future__ import annotations

import collections
import logging
import math
import re
import time

import numpy as np
import serial
import zenoh

from planning import JointState
from robots import BadRequest, Robot, Stepper

from .adapter import ControllerFault, SerialAdapter, actuators_of
from .trajectory_message import Command

log = logging.getLogger("armd.grbl")

RX_BUFFER = 128  # [bytes] GRBL's serial receive buffer
AXES = "XYZABC"
_STATUS = re.compile(r"<([A-Za-z]+(?::\d)?)\|MPos:([-\d.,]+)")  # state with its sub-state: Hold:0


class GrblAdapter(SerialAdapter):
    kind = "grbl"

    def __init__(self, session: zenoh.Session, robot: Robot, port: str, *, baud: int | None = None,
                 prefix: str = "armd", state_hz: float = 50.0, timeout: float = 0.5, check_period: float = 0.5,
                 margin: float = 1.25, serial_port: serial.SerialBase | None = None) -> None:
        self.steppers = actuators_of(robot, Stepper, "GRBL")
        self.axes = [a.axis for a in self.steppers]
        if any(ax not in AXES for ax in self.axes):
            raise BadRequest(f"GRBL axes are {', '.join(AXES)}; {robot.name} uses {', '.join(self.axes)}", field="axis")
        self.timeout = timeout  # [s] how long the controller may take to answer (the port's reads poll)
        super().__init__(session, robot, port, baud=baud or int(robot.controller.get("baud", 115200)),  # type: ignore[call-overload]
                         timeout=0.02, write_timeout=timeout, prefix=prefix, state_hz=state_hz,
                         check_period=check_period, serial_port=serial_port)
        self._buffer = b""
        self._trouble: str | None = None
        self._pending: collections.deque[int] = collections.deque()  # lengths of unacknowledged lines
        self._queue: list[bytes] = []  # lines of the running trajectory not sent yet
        self._sent_index = -1
        self._state = "Unknown"
        self._mpos = np.zeros(len(self.axes))
        self._last_status = 0.0
        self._welcome(reset_first=False)
        lim = robot.limits
        settings: list[tuple[int, float]] = []
        for j, (act, ax) in enumerate(zip(self.steppers, self.axes, strict=True)):
            i = AXES.index(ax)
            row = robot.actuators.M[j]
            vmax = float(np.abs(row) @ lim.velocity)  # actuator angle rate bound [rad/s]
            amax = float(np.abs(row) @ lim.acceleration)
            settings += [(100 + i, act.steps_per_degree), (110 + i, math.degrees(vmax) * 60 * margin),
                         (120 + i, math.degrees(amax) * margin)]
        for key, value in settings:
            self._command(f"${key}={value:.4f}")
        self._command("G90")
        self._poll_status(wait=True)
        self._q = self._joints(self._mpos)
        self._v = np.zeros(robot.nq)
        self._a = np.zeros(robot.nq)
        self.activate()

    # -- the wire ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        try:
            with self._io:
                self.serial.write(data)
        except (serial.SerialException, serial.SerialTimeoutException) as e:
            raise ControllerFault(f"GRBL on {self.port}: write failed: {e}") from None

    def _lines(self) -> list[str]:
        """Complete lines received so far (status reports included)."""
        try:
            with self._io:
                waiting = self.serial.in_waiting
                chunk = self.serial.read(waiting) if waiting else b""
        except serial.SerialException as e:
            raise ControllerFault(f"GRBL on {self.port}: read failed: {e}") from None
        self._buffer += chunk
        *lines, self._buffer = self._buffer.split(b"\n")
        return [ln.decode(errors="replace").strip() for ln in lines if ln.strip()]

    def _handle(self, line: str) -> None:
        if line == "ok":
            if self._pending:
                self._pending.popleft()
        elif line.startswith("error:"):
            if self._pending:
                self._pending.popleft()
            self._trouble = f"GRBL answered {line} (see GRBL's error codes)"
        elif line.startswith("ALARM:"):
            self._trouble = f"GRBL raised {line}"
        elif line.startswith("<"):
            m = _STATUS.match(line)
            if m:
                self._state = m.group(1)
                vals = [float(v) for v in m.group(2).split(",")]
                self._mpos = np.array([vals[AXES.index(ax)] for ax in self.axes])
                self._last_status = time.monotonic()

    def _pump(self) -> None:
        """Read and handle what GRBL said; raise an error or alarm it reported."""
        for line in self._lines():
            self._handle(line)
        if self._trouble:
            trouble, self._trouble = self._trouble, None
            raise ControllerFault(trouble)

    def _welcome(self, *, reset_first: bool) -> None:
        deadline = time.monotonic() + 3.0
        if reset_first:
            self._write(b"\x18")
        seen = ""
        while time.monotonic() < deadline:
            for line in self._lines():
                seen = line
                if line.startswith("Grbl"):
                    self._pending.clear()
                    return
            if not reset_first and time.monotonic() > deadline - 2.0:
                self._write(b"\x18")  # no welcome on opening: reset it
                reset_first = True
            time.sleep(0.005)
        raise ControllerFault(f"no GRBL answers on {self.port} (last: {seen!r})")

    def _command(self, line: str) -> None:
        """Send one line and wait for its ``ok`` (set-up only; streaming uses character counting)."""
        self._pending.append(len(line) + 1)
        self._write((line + "\n").encode())
        deadline = time.monotonic() + self.timeout * 4
        while self._pending:
            self._pump()
            time.sleep(0.001)
            if time.monotonic() > deadline:
                raise ControllerFault(f"GRBL on {self.port} did not acknowledge {line!r}")

    def _poll_status(self, wait: bool = False) -> None:
        asked = time.monotonic()
        self._write(b"?")
        while wait and self._last_status < asked:
            self._pump()
            time.sleep(0.001)
            if time.monotonic() - asked > self.timeout:
                raise ControllerFault(f"GRBL on {self.port} does not answer status requests")

    def _joints(self, degrees: np.ndarray) -> np.ndarray:
        steps = np.array([d * a.steps_per_degree for d, a in zip(degrees, self.steppers, strict=True)])
        return self.robot.actuators.joints_from_commands(steps, tol=np.inf)

    def _flush(self) -> None:
        """Stop GRBL and empty its buffers, keeping its position: feed hold, wait, soft reset."""
        self._write(b"!")
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            self._poll_status(wait=True)
            if self._state in ("Hold:0", "Idle", "Alarm"):  # not Hold:1: a reset while decelerating alarms
                break
            time.sleep(0.01)
        self._write(b"\x18")
        self._welcome(reset_first=False)
        self._pending.clear()
        self._queue = []
        if self._state == "Alarm":
            self._command("$X")
        self._command("G90")

    # -- the Adapter hooks ----------------------------------------------------------------------

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        if first:
            if self._pending or self._state not in ("Idle", "Unknown"):
                self._flush()  # a running trajectory is replaced: stop it and empty GRBL's buffer
            self._queue = self._segments(cmd)
            self._sent_index = 0
        self._pump()
        # send ahead while GRBL's receive buffer has room (character counting)
        while self._queue and sum(self._pending) + len(self._queue[0]) <= RX_BUFFER:
            line = self._queue.pop(0)
            self._pending.append(len(line))
            self._write(line)
        k = min(int(t * cmd.rate_hz), len(cmd.times) - 1)
        self._v, self._a = cmd.velocity[k].copy(), cmd.acceleration[k].copy()
        if self._queue or self._pending:
            return False
        self._poll_status(wait=True)
        return self._state == "Idle" and t >= cmd.duration

    def _segments(self, cmd: Command) -> list[bytes]:
        """One ``G1`` per sample after the first: to its whole-step position, in one period."""
        dt = 1.0 / cmd.rate_hz
        out = []
        prev = cmd.commands[0]
        elapsed = 0.0
        for k in range(1, len(cmd.times)):
            steps = cmd.commands[k]
            elapsed += dt
            if np.array_equal(steps, prev):
                continue  # no whole step to make: the next segment takes the time too (a G4 would drain GRBL)
            deg = [s / a.steps_per_degree for s, a in zip(steps.tolist(), self.steppers, strict=True)]
            prev_deg = [s / a.steps_per_degree for s, a in zip(prev.tolist(), self.steppers, strict=True)]
            dist = math.dist(deg, prev_deg)
            words = "".join(f"{ax}{d:.4f}" for ax, d in zip(self.axes, deg, strict=True))
            out.append(f"G1{words}F{max(dist / elapsed * 60.0, 1.0):.2f}\n".encode())
            prev = steps
            elapsed = 0.0
        return out

    def hold(self) -> None:
        self._write(b"!")
        self._v = np.zeros(self.robot.nq)
        self._a = np.zeros(self.robot.nq)

    def measure(self) -> JointState:
        """The position GRBL last reported (a status report is asked for at every call: the
        control loop parses the answer)."""
        self._write(b"?")
        return JointState(self._joints(self._mpos), self._v.copy(), self._a.copy())

    def check(self) -> None:
        self._pump()
        self._poll_status(wait=True)

    def shutdown(self) -> None:
        try:
            self.serial.close()
        except Exception:  # already gone
            log.debug("close failed", exc_info=True)
