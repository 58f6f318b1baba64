"""The SSC-32 adapter: servo arms on a Lynxmotion SSC-32 / SSC-32U (seeds 000 and 003).

``armd adapter ssc32 ROBOT --port /dev/ttyUSB0 [--baud B] [--state-dir DIR]``. The port may be
any pyserial URL (``/dev/ttyUSB0``, a pseudo-terminal, ``socket://host:port``); the baud rate
defaults to the arm's ``[controller] baud`` (the SSC-32U leaves the factory at 9600).

The board moves each servo linearly from where it is to a group move's pulse in ``T``
milliseconds, then holds; a new group move replaces the running one from where the servos
are. The adapter keeps a model of that motion (where the board is heading, from where, until
when, as the board interpolates it) and streams a trajectory one group move at a time, in
order, never skipping a sample:

- Each move is sent ``lead`` before the board reaches its previous one, toward the next
  sample, so the board is never idle while the adapter is on time, and a late adapter (up to
  ``lead``) only shortens the move in hand. Its ``T`` is the longest of: the trajectory's own
  schedule (one sample period after the previous move's end), every joint's distance over its
  velocity limit, and what keeps the change of speed from the move in hand within every
  acceleration limit (over one period). So a late adapter, a stalled process or a slow link
  re-time the rest of the trajectory: slower, from where the board is, ramping up from rest
  when the board had stopped; the board is never asked to go faster than the limits, and
  nothing catches up by jumping.
- Bandwidth: each move's bytes, times the moves per second, against the link (10 bits a byte
  at the baud rate). A trajectory sampled faster than the link carries is streamed every
  ``stride``-th sample (at most 60% of the link: the rest is for the checks); one that would
  need moves further apart than ``MAX_PERIOD`` is refused before any pulse is sent, naming the
  baud rate.
- Checks never block the stream: every ``query_period`` a ``QP`` of every channel is written,
  and its answer read by later passes of the control loop; no answer within ``timeout`` is a
  fault, and so is an answer that disagrees with the model by more than ``QP_TOL`` (someone
  else moved the servos, the board was reset).

Start-up: ``VER`` must answer. Then ``QP``: a board already outputting pulses on every channel
(the adapter restarted, the board stayed powered) is adopted as it is, with no pulse change. A
board just powered outputs none, and a hobby servo's position is unknown until its first
pulse: its first command is a jump, at the servo's own speed, whatever ``T`` says. The adapter
says so in its log and commands the pose the arm was left at (the last commanded pose, kept
per arm in ``state_dir`` when a trajectory ends and when the adapter stops), else neutral;
the state it reports says ``source: "commanded"`` (hobby servos report no position).

The gripper, a separate channel, opens and closes on ``<prefix>/<robot>/gripper``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import serial
import zenoh

from planning import JointState
from robots import BadRequest, Robot, Servo

from .adapter import ControllerFault, SerialAdapter, actuators_of
from .trajectory_message import Command, FloatArray

log = logging.getLogger("armd.ssc32")

LINK_SHARE = 0.6  # of the link's bytes per second the stream may use
MAX_PERIOD = 0.25  # [s] the longest step between streamed samples (farther: refused, the link is too slow)
LEAD = 0.05  # [s] at least this long before the board reaches a move, the next one is sent
QP_TOL = 25.0  # [us] how far a QP answer may be from the model (QP answers in 10 us, the model rounds)
T_MAX = 65.535  # [s] the longest T the board takes


def state_dir_default() -> Path:
    """Where adapters keep what must outlive them: ``$ARMD_STATE_DIR``, else ``$XDG_STATE_HOME/armd``,
    else ``~/.local/state/armd``."""
    if os.environ.get("ARMD_STATE_DIR"):
        return Path(os.environ["ARMD_STATE_DIR"])
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "armd"


class SSC32Adapter(SerialAdapter):
    kind = "ssc32"

    def __init__(self, session: zenoh.Session, robot: Robot, port: str, *, baud: int | None = None,
                 prefix: str = "armd", state_hz: float = 50.0, timeout: float = 0.5, query_period: float = 0.5,
                 state_dir: str | Path | None = None, lead: float = LEAD,
                 serial_port: serial.SerialBase | None = None) -> None:
        self.channels = [a.channel for a in actuators_of(robot, Servo, "SSC-32")]
        self.baud = int(baud or robot.controller.get("baud", 9600))  # type: ignore[call-overload]
        if self.baud <= 0:
            raise BadRequest(f"baud must be a positive number, got {self.baud}", field="baud")
        self.timeout = timeout  # [s] how long an answer may take
        self.query_period = query_period
        self.lead = lead
        self.state_file = Path(state_dir or state_dir_default()) / f"{robot.name}.ssc32.json"
        super().__init__(session, robot, port, baud=self.baud, timeout=timeout, write_timeout=timeout, prefix=prefix,
                         state_hz=state_hz, check_period=0.02, serial_port=serial_port)
        lim = robot.limits
        self._vmax, self._amax = lim.velocity, lim.acceleration
        # the board's motion, as the model has it: linear from _p0 at _t0 to _p1 at _t1, then held
        now = time.monotonic()
        self._p0 = self._p1 = np.array(robot.neutral, dtype=float)
        self._t0 = self._t1 = now
        self._link_free = now  # [s] when the link has carried everything written so far
        self._k = 0  # the running trajectory's sample the board is heading to
        self._stride = 1
        self._query: tuple[float, int] | None = None  # (when a QP was written, reply length)
        self._reply = b""
        self._next_query = now
        self._answered = self._faulted_at = -math.inf  # [s] the last QP answer; the last fault
        self._answer: FloatArray | None = None  # [us] the last QP answer
        self.version = self._ask(b"VER\r", until=b"\r").decode(errors="replace").strip()
        if not self.version:
            self.serial.close()
            raise ControllerFault(f"no SSC-32 answers on {port} at {self.baud} baud (VER got no reply)")
        log.info("%s on %s at %d baud: %s", robot.name, port, self.baud, self.version)
        self._start_up()
        self.activate()

    # -- start-up -------------------------------------------------------------------------

    def _start_up(self) -> None:
        """Adopt a board that outputs pulses; else command the pose the arm was left at (a jump)."""
        deadline = time.monotonic() + 5.0
        while self._ask(b"Q\r") == b"+" and time.monotonic() < deadline:  # a move in progress: let it end
            time.sleep(0.02)
        pulses = self._query_pulses()
        amap = self.robot.actuators
        if all(pulses > 0):
            q = amap.joints_from_commands(pulses, tol=np.inf)
            lim = self.robot.limits
            if not lim.contains(q, tol=0.02):
                bad = lim.violations(q, tol=0.02)
                self.serial.close()
                raise ControllerFault(f"the SSC-32 on {self.port} holds {self.robot.name} outside its limits "
                                      f"({bad[0].message}): move the arm inside them by hand (power off) first")
            q = np.minimum(np.maximum(q, lim.lower), lim.upper)
            log.info("%s: the board outputs pulses already (%s us): adopted as it is",
                     self.robot.name, " ".join(str(int(p)) for p in pulses))
            self._p0 = self._p1 = q
            return
        q, where = self._left_at()
        log.warning("%s: the SSC-32 outputs no pulses (just powered): a hobby servo's position is unknown until "
                    "its first pulse, so the arm JUMPS to %s at the servos' own speed now", self.robot.name, where)
        self._send(amap.commands(q), None)
        self._p0 = self._p1 = q
        self._t0 = self._t1 = time.monotonic()

    def _left_at(self) -> tuple[FloatArray, str]:
        """The pose the arm was last commanded to (kept in ``state_file``), else neutral."""
        try:
            saved = json.loads(self.state_file.read_text())
            q = self.robot.joint_vector(saved["position"])
            if self.robot.limits.contains(q):
                return q, f"the pose it was left at ({self.state_file})"
            log.warning("%s: %s is outside the limits: ignored", self.robot.name, self.state_file)
        except FileNotFoundError:
            pass
        except (ValueError, KeyError, TypeError, OSError) as e:
            log.warning("%s: cannot read %s (%s): ignored", self.robot.name, self.state_file, e)
        return np.array(self.robot.neutral, dtype=float), "the neutral pose"

    def _save_pose(self) -> None:
        q = self._p1
        try:
            self.state_file.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.state_file.with_suffix(".tmp")
            tmp.write_text(json.dumps({"robot": self.robot.name, "position": q.tolist(),
                                       "pulses": self.robot.actuators.commands(q).tolist(), "time": time.time()}))
            tmp.replace(self.state_file)
        except OSError as e:
            log.warning("%s: cannot keep the pose in %s: %s", self.robot.name, self.state_file, e)

    # -- the wire ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        try:
            with self._io:
                self.serial.write(data)
        except (serial.SerialException, serial.SerialTimeoutException) as e:
            raise ControllerFault(f"SSC-32 on {self.port}: write failed: {e}") from None
        now = time.monotonic()
        self._link_free = max(self._link_free, now) + len(data) * 10.0 / self.baud

    def _ask(self, request: bytes, *, until: bytes | None = None, size: int = 1) -> bytes:
        """A blocking question (start-up only: the control loop never waits for the board)."""
        try:
            with self._io:
                self.serial.reset_input_buffer()
                self.serial.write(request)
                if until is not None:
                    return bytes(self.serial.read_until(until))
                return bytes(self.serial.read(size))
        except (serial.SerialException, serial.SerialTimeoutException) as e:
            raise ControllerFault(f"SSC-32 on {self.port}: {e}") from None

    def _qp_request(self) -> bytes:
        return ("".join(f"QP{ch}" for ch in self.channels) + "\r").encode()

    def _query_pulses(self) -> FloatArray:
        reply = self._ask(self._qp_request(), size=len(self.channels))
        if len(reply) != len(self.channels):
            raise ControllerFault(f"SSC-32 on {self.port} does not answer QP ({reply!r})")
        return np.array([10.0 * b for b in reply])

    def _send(self, pulses: np.ndarray, duration_ms: int | None) -> None:
        line = "".join(f"#{ch}P{int(pw)}" for ch, pw in zip(self.channels, pulses.tolist(), strict=True))
        if duration_ms is not None:
            line += f"T{duration_ms}"
        self._write((line + "\r").encode())

    def _line_bytes(self) -> int:
        """The bytes of one group move of every channel (the longest form)."""
        return sum(len(f"#{ch}P2500") for ch in self.channels) + len("T65535\r")

    # -- the model of the board ------------------------------------------------------------

    def _at(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Where the board is at time ``t`` [s], and how fast it moves [rad/s]."""
        if t >= self._t1 or self._t1 <= self._t0:
            return self._p1.copy(), np.zeros(self.robot.nq)
        v = (self._p1 - self._p0) / (self._t1 - self._t0)
        return self._p0 + v * (max(t, self._t0) - self._t0), v

    def _duration(self, d: FloatArray, v0: FloatArray, t_nominal: float, window: float) -> float:
        """The group move's time [s] for a displacement ``d`` [rad] started at speed ``v0``:
        at least ``t_nominal``; every joint within its velocity limit (hard); the change of speed
        within ``a * window`` per joint (where no time can keep it, the least violation)."""
        u_hi = 1.0 / max(t_nominal, 1e-3)
        moving = np.abs(d) > 1e-12
        if moving.any():
            u_hi = min(u_hi, float(np.min(self._vmax[moving] / np.abs(d[moving]))))
        c = self._amax * window
        lo = np.full(len(d), -np.inf)
        hi = np.full(len(d), np.inf)
        lo[moving] = np.minimum((v0 - c)[moving] / d[moving], (v0 + c)[moving] / d[moving])
        hi[moving] = np.maximum((v0 - c)[moving] / d[moving], (v0 + c)[moving] / d[moving])
        still_ok = np.all(np.abs(v0[~moving]) <= c[~moving] * (1 + 1e-9))
        u_lo = max(float(np.max(lo)), 1.0 / T_MAX)
        u = min(u_hi, float(np.min(hi)))
        if not (still_ok and u_lo <= u):  # no time keeps every joint's acceleration: the least violation

            def violation(x: float) -> float:
                return float(np.max(np.abs(x * d - v0) / c))

            a, b = 1.0 / T_MAX, u_hi
            for _ in range(60):
                m1, m2 = a + (b - a) / 3, b - (b - a) / 3
                if violation(m1) <= violation(m2):
                    b = m2
                else:
                    a = m1
            u = (a + b) / 2
            log.warning("%s: no group-move time keeps every acceleration limit (%.2f x): the least violation",
                        self.robot.name, violation(u))
        return 1.0 / u

    def _move_to(self, k: int, cmd: Command, t_nominal_end: float, window: float) -> None:
        """Send the group move toward sample ``k`` of ``cmd``, to end no earlier than ``t_nominal_end``."""
        now = time.monotonic()
        nbytes = self._line_bytes()
        arrival = max(now, self._link_free) + nbytes * 10.0 / self.baud  # the board starts it then
        p0, v0 = self._at(arrival)
        q = cmd.position[k]
        d = q - p0
        T = self._duration(d, v0, t_nominal_end - arrival, window)
        ms = max(1, round(T * 1000.0))
        while np.any(np.abs(d) > self._vmax * (ms / 1000.0) * (1 + 1e-9)):  # rounding never makes it faster
            ms += 1
        ms = min(ms, 65535)
        self._send(cmd.commands[k], ms)
        self._p0, self._t0, self._p1, self._t1 = p0, arrival, q.copy(), arrival + ms / 1000.0

    # -- the Adapter hooks ----------------------------------------------------------------------

    def admit(self, cmd: Command) -> None:
        """Refuse, before any pulse is sent, a trajectory the link cannot carry."""
        self.stride_for(cmd)

    def stride_for(self, cmd: Command) -> int:
        """Every how many samples a group move is sent, so the stream fits ``LINK_SHARE`` of the link."""
        per_second = LINK_SHARE * self.baud / 10.0 / self._line_bytes()  # group moves the link carries [1/s]
        stride = max(1, math.ceil(cmd.rate_hz / per_second - 1e-9))
        if stride / cmd.rate_hz > MAX_PERIOD + 1e-9 and len(cmd.times) > 1:
            raise BadRequest(f"at {self.baud} baud the link carries {per_second:.1f} group moves of "
                             f"{len(self.channels)} servos a second: samples {stride / cmd.rate_hz * 1000:.0f} ms "
                             f"apart, more than {MAX_PERIOD * 1000:.0f} ms; raise the SSC-32's baud rate "
                             f"(--baud and the board's)", field="rate_hz", baud=self.baud)
        return stride

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        self._poll_reply()
        now = time.monotonic()
        last = len(cmd.times) - 1
        if first:
            self._k = 0
            self._stride = self.stride_for(cmd)
        period = self._stride / cmd.rate_hz
        lead = max(self.lead, period)
        if self._k < last and (first or now >= self._t1 - lead):
            k = min(self._k + self._stride, last)
            base = now + lead if first else max(self._t1, now)
            self._move_to(k, cmd, base + (cmd.times[k] - cmd.times[self._k]), period)
            self._k = k
        return self._k >= last and now >= self._t1

    def finished(self, cmd: Command) -> None:
        self._save_pose()

    def hold(self) -> None:
        """Stop sending: the board completes the move in hand (at most ``lead`` plus a period) and holds."""
        return None

    def measure(self) -> JointState:
        p, v = self._at(time.monotonic())
        return JointState(p, v, np.zeros(self.robot.nq))

    def check(self) -> None:
        """The control loop's look at the board, never waiting: read a QP answer if it came,
        fault if it is overdue or disagrees with the model, ask again when it is time."""
        self._poll_reply()
        now = time.monotonic()
        overdue = self._query is not None and now - self._query[0] > self.timeout + self._query[1] * 10.0 / self.baud
        if overdue:
            self._query = None
            self._reply = b""
        if self.fault:  # recovered only once the board has answered since, from where it says it is
            if self._answered > self._faulted_at and self._resync():
                return
            if self._query is None:
                self._next_query = now
        elif overdue:
            self._faulted_at = now
            raise ControllerFault(f"SSC-32 on {self.port} does not answer (QP got no reply in {self.timeout} s)")
        if self._query is None and now >= self._next_query:
            request = self._qp_request()
            with self._io:
                try:
                    self.serial.reset_input_buffer()
                except serial.SerialException as e:
                    raise ControllerFault(f"SSC-32 on {self.port}: {e}") from None
            self._write(request)
            self._query = (max(now, self._link_free), len(self.channels))
            self._next_query = now + self.query_period
        if self.fault:
            raise ControllerFault(self.fault)

    def _poll_reply(self) -> None:
        if self._query is None:
            return
        try:
            with self._io:
                waiting = self.serial.in_waiting
                chunk = self.serial.read(waiting) if waiting else b""
        except serial.SerialException as e:
            raise ControllerFault(f"SSC-32 on {self.port}: read failed: {e}") from None
        self._reply += chunk
        asked, size = self._query
        if len(self._reply) < size:
            return
        reply, self._reply, self._query = self._reply[:size], b"", None
        self._answered = time.monotonic()
        self._answer = np.array([10.0 * b for b in reply])
        if self.fault:
            return  # answering again: the base's recovery follows
        try:
            self._compare(self._answer, asked, self._answered)
        except ControllerFault:
            self._faulted_at = self._answered
            raise

    def _resync(self) -> bool:
        """The model put where the board's last QP answer says the arm is; False if that is
        not a pose inside the limits (the fault stays)."""
        pulses = self._answer
        if pulses is None or not np.all(pulses > 0):
            return False
        q = self.robot.actuators.joints_from_commands(pulses, tol=np.inf)
        if not self.robot.limits.contains(q, tol=0.02):
            return False
        self._p0 = self._p1 = np.minimum(np.maximum(q, self.robot.limits.lower), self.robot.limits.upper)
        self._t0 = self._t1 = time.monotonic()
        return True

    def _compare(self, pulses: FloatArray, asked: float, answered: float) -> None:
        """A QP answer against the model, anywhere between when it was asked and answered."""
        amap = self.robot.actuators
        ts = np.linspace(asked, answered, 5)
        model = np.array([amap.command_values(self._at(float(t))[0]) for t in ts])  # pulses [us]
        lo, hi = model.min(axis=0) - QP_TOL, model.max(axis=0) + QP_TOL
        off = np.maximum(lo - pulses, pulses - hi)
        if np.any(off > 0):
            i = int(np.argmax(off))
            raise ControllerFault(f"SSC-32 on {self.port}: channel {self.channels[i]} outputs {pulses[i]:.0f} us, "
                                  f"the adapter commanded {model[-1, i]:.0f} us (someone else moved it, or the board "
                                  "was reset)")

    def grip(self, opening: float) -> None:
        """Open (1) or close (0) the gripper, or anything between: its own channel, over 0.5 s."""
        g = self.robot.gripper
        if g is None:
            raise BadRequest(f"{self.robot.name} has no gripper", field="gripper")
        self._write(f"#{g.channel}P{g.pulse(opening)}T500\r".encode())
        self.gripper_opening = opening

    def shutdown(self) -> None:
        self._save_pose()
        try:
            self.serial.close()
        except Exception:  # already gone
            log.debug("close failed", exc_info=True)
