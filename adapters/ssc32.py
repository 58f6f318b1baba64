"""The SSC-32 adapter: servo arms on a Lynxmotion SSC-32 / SSC-32U (seeds 000 and 003).

``armd adapter ssc32 ROBOT --port /dev/ttyUSB0 [--baud B] [--state-dir DIR]``. The port may be
any pyserial URL (``/dev/ttyUSB0``, a pseudo-terminal, ``socket://host:port``); the baud rate
defaults to the arm's ``[controller] baud`` (the SSC-32U leaves the factory at 9600).

The board moves each servo linearly from where it is to a group move's pulse in ``T``
milliseconds, then holds; a new group move replaces the running one from where the servos
are. The adapter keeps a model of that motion (where the board is heading, from where, until
when, as the board interpolates it) and streams a trajectory one group move a period:

- Each move lasts ``lead`` and a period, and the next one replaces it a period in: the board
  is never idle while the adapter is on time, and a late adapter (up to ``lead``) only
  lengthens the move in hand. Its speed, per joint, is the plan's average over the move
  ahead, from where the board is (a board off the plan converges on it), within one period's
  change of speed of the move in hand (every acceleration limit, over the time since the
  previous change) and within every velocity limit, whole-microsecond pulses allowed for; its
  target is where that speed leads, kept inside the position limits. The plan's clock
  advances with the board's, by at most ``MAX_SLIP`` periods a move: a late adapter, a
  stalled process or a slow link re-time the rest of the trajectory, slower, from where the
  board is, ramping up from rest when the board had stopped; nothing catches up by jumping.
  The last move ends at the trajectory's end, once the board may stop there within the
  limits; a stop never reverses a joint.
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

import collections
import json
import logging
import math
import os
import time
from pathlib import Path

import numpy as np
import serial
import zenoh

from armd.errors import BadRequest, ControllerFault
from armd.planning import JointState
from armd.robots import Robot, Servo

from .base import actuators_of
from .serial_port import SerialAdapter
from .trajectory_message import Command, FloatArray

log = logging.getLogger(__name__)

LINK_SHARE = 0.6  # of the link's bytes per second the stream may use
MAX_PERIOD = 0.25  # [s] the longest step between streamed samples (farther: refused, the link is too slow)
LEAD = 0.05  # [s] at least this long before the board reaches a move, the next one is sent
MAX_LEAD = 0.25  # [s] the most the lead grows to on a busy machine
LATENESS_DECAY = 0.5  # per second: how fast the lead forgets a late pass of the control loop
QP_TOL = 25.0  # [us] how far a QP answer may be from the model (QP answers in 10 us, the model rounds)
ARRIVAL_TOL = 2e-4  # [s] how far from when a move is aimed for the board may have it (else it is aimed again)
MAX_SLIP = 1.5  # periods: the most the plan's clock advances between two moves (later: the plan waits)
RUN_TICK = 0.001  # [s] the control loop's period while streaming (sends on time: regular changes of speed)


def _on_piece(p0: FloatArray, t0: float, p1: FloatArray, t1: float, t: float) -> tuple[FloatArray, FloatArray]:
    """On the linear piece from ``p0`` at ``t0`` to ``p1`` at ``t1``, held after: position and speed at ``t``."""
    if t >= t1 or t1 <= t0:
        return p1.copy(), np.zeros(len(p1))
    v = (p1 - p0) / (t1 - t0)
    return p0 + v * (max(t, t0) - t0), v


def state_dir_default() -> Path:
    """Where adapters keep what must outlive them: ``$ARMD_STATE_DIR``, else ``$XDG_STATE_HOME/armd``,
    else ``~/.local/state/armd``."""
    if os.environ.get("ARMD_STATE_DIR"):
        return Path(os.environ["ARMD_STATE_DIR"])
    xdg = os.environ.get("XDG_STATE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".local" / "state") / "armd"


class SSC32Adapter(SerialAdapter):
    kind = "ssc32"
    run_tick = RUN_TICK

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        port: str,
        *,
        baud: int | None = None,
        prefix: str = "armd",
        state_hz: float = 50.0,
        timeout: float = 0.5,
        query_period: float = 0.5,
        state_dir: str | Path | None = None,
        lead: float = LEAD,
        serial_port: serial.SerialBase | None = None,
    ) -> None:
        self.channels = [a.channel for a in actuators_of(robot, Servo, "SSC-32")]
        self.baud = int(baud or robot.controller.get("baud", 9600))  # type: ignore[call-overload]
        if self.baud <= 0:
            raise BadRequest(f"baud must be a positive number, got {self.baud}", field="baud")
        self.timeout = timeout  # [s] how long an answer may take
        self.query_period = query_period
        self.lead = lead
        self.state_file = Path(state_dir or state_dir_default()) / f"{robot.name}.ssc32.json"
        super().__init__(
            session,
            robot,
            port,
            baud=self.baud,
            timeout=timeout,
            write_timeout=timeout,
            prefix=prefix,
            state_hz=state_hz,
            check_period=0.02,
            serial_port=serial_port,
        )
        lim = robot.limits
        self._vmax, self._amax = lim.velocity, lim.acceleration
        amap = robot.actuators  # [rad] per joint, half a microsecond of the servo that moves it most finely
        self._half_pulse = np.array(
            [
                0.5 * max(a.resolution / abs(m) for a, m in zip(amap.actuators, amap.M[:, j], strict=True) if m)
                for j in range(robot.nq)
            ]
        )
        # the board's motion, as the model has it: linear from _p0 at _t0 to _p1 at _t1, then held
        now = time.monotonic()
        self._p0 = self._p1 = np.array(robot.neutral, dtype=float)
        self._t0 = self._t1 = now
        self._link_free = now  # [s] when the link has carried everything written so far
        self._pieces: collections.deque[tuple[FloatArray, float, FloatArray, float]] = collections.deque(maxlen=256)
        self._tau = 0.0  # [s] the plan's time the running move was aimed from
        self._rhythm = now  # [s] the earliest the next move of a trajectory should reach the board
        self._settled = True  # the board heads for the trajectory's end slowly enough to stop there
        self._lateness = 0.0  # [s] how late the control loop has written moves lately (decaying)
        self._seen_at = now
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
            # QP answers in 10 us (the pulse / 10, truncated): the pose kept at the last stop, if
            # the board still outputs it, is exact; else the middle of what QP allows
            kept, _ = self._left_at()
            exact = amap.command_values(kept)
            q = (
                kept
                if np.all((exact >= pulses - 0.5) & (exact < pulses + 10.5))
                else amap.joints_from_commands(pulses + 5.0, tol=np.inf)
            )
            lim = self.robot.limits
            if not lim.contains(q, tol=0.02):
                bad = lim.violations(q, tol=0.02)
                self.serial.close()
                raise ControllerFault(
                    f"the SSC-32 on {self.port} holds {self.robot.name} outside its limits "
                    f"({bad[0].message}): move the arm inside them by hand (power off) first"
                )
            q = lim.clip(q)
            log.info(
                "%s: the board outputs pulses already (%s us): adopted as it is",
                self.robot.name,
                " ".join(str(int(p)) for p in pulses),
            )
            self._hold_at(q)
            return
        q, where = self._left_at()
        log.warning(
            "%s: the SSC-32 outputs no pulses (just powered): a hobby servo's position is unknown until "
            "its first pulse, so the arm JUMPS to %s at the servos' own speed now",
            self.robot.name,
            where,
        )
        self._send(amap.commands(q), None)
        if not np.all(self._query_pulses() > 0):  # (asked after the move: answered once the board has it)
            self.serial.close()
            raise ControllerFault(f"the SSC-32 on {self.port} did not take its first command")
        self._hold_at(q)

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
            tmp.write_text(
                json.dumps(
                    {
                        "robot": self.robot.name,
                        "position": q.tolist(),
                        "pulses": self.robot.actuators.commands(q).tolist(),
                        "time": time.time(),
                    }
                )
            )
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

    def _line(self, pulses: np.ndarray, duration_ms: int | None) -> bytes:
        """A group move of every channel: ``#<ch>P<pw>...[T<ms>]\\r``."""
        line = "".join(f"#{ch}P{int(pw)}" for ch, pw in zip(self.channels, pulses.tolist(), strict=True))
        if duration_ms is not None:
            line += f"T{duration_ms}"
        return (line + "\r").encode()

    def _send(self, pulses: np.ndarray, duration_ms: int | None) -> None:
        self._write(self._line(pulses, duration_ms))

    def _line_bytes(self) -> int:
        """The bytes of one group move of every channel (the longest form)."""
        return sum(len(f"#{ch}P2500") for ch in self.channels) + len("T65535\r")

    # -- the model of the board ------------------------------------------------------------

    def _hold_at(self, q: FloatArray) -> None:
        """The model: the board holds ``q`` from now on (what came before is forgotten)."""
        self._p0, self._p1 = q.copy(), q.copy()
        self._t0 = self._t1 = time.monotonic()
        self._pieces.clear()
        self._pieces.append((self._p0, self._t0, self._p1, self._t1))

    def _at(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Where the board is at time ``t`` [s] (now or later), and how fast it moves [rad/s]."""
        return _on_piece(self._p0, self._t0, self._p1, self._t1, t)

    def _was_at(self, t: float) -> FloatArray:
        """Where the board was at time ``t`` [s], which may be a few pieces ago."""
        for p0, t0, p1, t1 in reversed(self._pieces):
            if t >= t0:
                return _on_piece(p0, t0, p1, t1, t)[0]
        return self._pieces[0][0].copy() if self._pieces else self._at(t)[0]

    def _stream(self, cmd: Command, first: bool, period: float, lead: float) -> None:
        """Send the next group move of ``cmd`` (:meth:`_aim`), timed for when the board will
        have it: if this thread was held up meanwhile, aimed again."""
        ms = max(1, round((lead + period) * 1000.0))  # the next move replaces it a period in: a lead to spare
        arrival = max(time.monotonic(), self._link_free) + self._line_bytes() * 10.0 / self.baud
        for _ in range(3):
            x, tau, final = self._aim(cmd, arrival, first, period, ms / 1000.0)
            pulses = self.robot.actuators.commands(x)
            line = self._line(pulses, ms)
            actual = max(time.monotonic(), self._link_free) + len(line) * 10.0 / self.baud
            if abs(actual - arrival) <= ARRIVAL_TOL:
                break
            arrival = actual + ARRIVAL_TOL  # (the time to aim again)
        written = time.monotonic()
        arrival = max(written, self._link_free) + len(line) * 10.0 / self.baud
        p0 = self._at(arrival)[0]
        self._write(line)
        target = self.robot.actuators.joints_from_commands(pulses, tol=np.inf)
        self._p0, self._t0, self._p1, self._t1 = p0, arrival, target, arrival + ms / 1000.0
        self._pieces.append((self._p0, self._t0, self._p1, self._t1))
        self._tau = tau
        self._rhythm = arrival + period  # the next move arrives no sooner: no piece shorter than a period
        self._settled = final

    def _aim(
        self, cmd: Command, arrival: float, first: bool, period: float, span: float
    ) -> tuple[FloatArray, float, bool]:
        """A group move the board starts at ``arrival`` [s] and that lasts ``span`` [s]: its
        target [rad], the plan's time it was aimed from [s], and whether it is the last one
        (it ends at the trajectory's end, slowly enough to stop there).

        Each joint's speed is the plan's average over the move ahead, from where the board
        is (so a board ahead of or behind the plan converges on it), within one period's
        change of speed of the move in hand (the acceleration limit, over the time since the
        previous change) and within the velocity limit; the target is where that speed
        leads in ``span``, kept inside the position limits. The plan's clock advances with
        the board's, by at most ``MAX_SLIP`` periods a move: a late move re-times the rest
        of the trajectory, slower, from where the board is.
        """
        p0, v0 = self._at(arrival)
        tau = 0.0 if first else self._tau + min(arrival - self._t0, MAX_SLIP * period)
        # [rad/s] how far a speed may come out from what is aimed: whole-microsecond pulses, and a
        # start up to ARRIVAL_TOL from when it is aimed for (the board a little farther on, or not as far)
        rounding = (self._half_pulse + np.abs(v0) * ARRIVAL_TOL) / span
        c = np.maximum(self._amax * min(period, max(arrival - self._t0, 1e-3)) - rounding, 0.0)
        goal = self.robot.actuators.joints_from_commands(cmd.commands[-1], tol=np.inf)  # (as the board has it)
        if cmd.kind == "stop":  # a joint already past the stop's end stays where it is: a stop never reverses
            way = cmd.position[-1] - cmd.position[0]
            goal = np.where((goal - p0) * way < 0.0, p0, goal)
        if tau + span >= cmd.duration:  # the plan ends within this move: the goal, once the board may stop there
            d = goal - p0
            if np.all(np.abs(d) <= self._amax * period * span * (1 + 1e-9)) and np.all(
                np.abs(d / span - v0) <= c * (1 + 1e-9)
            ):
                return goal.copy(), tau, True
        ahead = cmd.sample_at(tau + span)[0]
        v = np.clip((ahead - p0) / span, v0 - c, v0 + c)
        if cmd.kind == "stop":  # a stop never reverses a joint
            v = np.where(v * v0 < 0.0, 0.0, v)
        v = np.clip(v, rounding - self._vmax, self._vmax - rounding)
        return self._inside(p0, p0 + v * span), tau, False

    def _inside(self, p0: FloatArray, x: FloatArray) -> FloatArray:
        """``x`` brought back toward ``p0``, along the way between them, as far as it must be to keep
        every position limit (the box, the coupled limits and the servos' ranges)."""
        if self._within(x):
            return x
        if not self._within(p0):
            return self.robot.limits.clip(p0)
        lo, hi = 0.0, 1.0
        for _ in range(30):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if self._within(p0 + mid * (x - p0)) else (lo, mid)
        return p0 + lo * (x - p0)

    def _within(self, q: FloatArray) -> bool:
        if not self.robot.limits.contains(q, tol=0.0):
            return False
        try:
            self.robot.actuators.commands(q)
        except BadRequest:
            return False
        return True

    # -- the Adapter hooks ----------------------------------------------------------------------

    def admit(self, cmd: Command) -> None:
        """Refuse, before any pulse is sent, a trajectory the link cannot carry."""
        self.stride_for(cmd)

    def stride_for(self, cmd: Command) -> int:
        """Every how many samples a group move is sent, so the stream fits ``LINK_SHARE`` of the link."""
        per_second = LINK_SHARE * self.baud / 10.0 / self._line_bytes()  # group moves the link carries [1/s]
        stride = max(1, math.ceil(cmd.rate_hz / per_second - 1e-9))
        if stride / cmd.rate_hz > MAX_PERIOD + 1e-9 and len(cmd.times) > 1:
            raise BadRequest(
                f"at {self.baud} baud the link carries {per_second:.1f} group moves of "
                f"{len(self.channels)} servos a second: samples {stride / cmd.rate_hz * 1000:.0f} ms "
                f"apart, more than {MAX_PERIOD * 1000:.0f} ms; raise the SSC-32's baud rate "
                f"(--baud and the board's)",
                field="rate_hz",
                baud=self.baud,
            )
        return stride

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        self._poll_reply()
        now = time.monotonic()
        if first:
            self._stride = self.stride_for(cmd)
            self._settled = False
        period = self._stride / cmd.rate_hz
        # the lead grows with how late this loop has run lately (a busy machine), up to MAX_LEAD
        self._lateness *= LATENESS_DECAY ** max(now - self._seen_at, 0.0)
        self._seen_at = now
        lead = min(max(self.lead, period, 2.0 * self._lateness), max(MAX_LEAD, period))
        if cmd.kind == "stop":  # a stop keeps its lead short: stalled in a stop, the board holds anyway
            lead = max(self.lead, period)
        link = max(self._link_free - now, 0.0) + self._line_bytes() * 10.0 / self.baud  # until the board has it
        due = self._rhythm - link  # when the next move should be written: a period after this one
        if not self._settled and (first or now >= due):
            if not first:
                self._lateness = max(self._lateness, now - due)
                if now + link > self._t1:  # the board got there first, and stopped
                    self._stopped_late(cmd, now + link - self._t1)
            self._stream(cmd, first, period, lead)
        return self._settled and now >= self._t1

    def _stopped_late(self, cmd: Command, late: float) -> None:
        """Said when the control loop ran so late (a stalled process) that the board finished its
        move and held: a stop at the speed it had, which no command of the SSC-32 can soften."""
        v = float(np.max(np.abs(self._p1 - self._p0) / max(self._t1 - self._t0, 1e-6) / self._vmax))
        log.warning(
            "%s: the adapter ran %.0f ms late: the board finished its move and held (from %.0f%% of a "
            "velocity limit); resuming from rest",
            self.robot.name,
            late * 1000,
            100 * v,
        )
        self.event("late", id=cmd.id, late=late, speed_ratio=v)

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
            if self._answered > self._faulted_at:
                why = self._resync()
                if why is None:
                    return
                self._faulted_at = self._answered
                self._query = None
                raise ControllerFault(why)
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

    def _resync(self) -> str | None:
        """The model put where the board's last QP answer says the arm is; else why not (the
        fault stays, with that reason)."""
        pulses = self._answer
        if pulses is None:
            return "no QP answer"
        if not np.all(pulses > 0):
            ch = self.channels[int(np.argmin(pulses))]
            return (
                f"SSC-32 on {self.port}: channel {ch} outputs 0 us (the board was reset or powered off): "
                "restart the adapter to command the arm's pose again"
            )
        q = self.robot.actuators.joints_from_commands(pulses, tol=np.inf)
        if not self.robot.limits.contains(q, tol=0.02):
            bad = self.robot.limits.violations(q, tol=0.02)[0].message
            return f"SSC-32 on {self.port} holds the arm outside its limits ({bad})"
        self._hold_at(self.robot.limits.clip(q))
        return None

    def _compare(self, pulses: FloatArray, asked: float, answered: float) -> None:
        """A QP answer against the model, anywhere between when it was asked and answered."""
        amap = self.robot.actuators
        ts = [t for _, t0, _, t1 in self._pieces for t in (t0, t1) if asked < t < answered]
        model = np.array([amap.command_values(self._was_at(float(t))) for t in (asked, *ts, answered)])  # [us]
        lo, hi = model.min(axis=0) - QP_TOL, model.max(axis=0) + QP_TOL
        off = np.maximum(lo - pulses, pulses - hi)
        if np.any(off > 0):
            i = int(np.argmax(off))
            raise ControllerFault(
                f"SSC-32 on {self.port}: channel {self.channels[i]} outputs {pulses[i]:.0f} us, "
                f"the adapter commanded {model[-1, i]:.0f} us (someone else moved it, or the board "
                "was reset)"
            )

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
