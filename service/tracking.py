"""The tracking stream, ``<prefix>/<robot>/track``: an arm that follows the latest target a
client puts (a leader arm, a gamepad, a program, a web page), within every limit, clear of its
world, and that brakes to rest when the puts stop.

One :class:`Tracker` per arm. A put (:mod:`.track_message`) is checked on the thread Zenoh
hands it to and kept (the latest wins: puts faster than ``MIN_PERIOD`` are coalesced); the
tracker's own thread turns it into a joint goal (``joints`` as they are, within the limits;
``target`` by the IK seeded with the last goal, kept on its branch; ``velocity`` by moving the
tool's point, pitch and roll at that rate) and plans a cycle (:func:`planning.online.track_step`):
Ruckig from the state of the trajectory the adapter runs, a sample ahead of now, to the goal,
braking to rest where the session's deadman runs out, checked against the world. The cycle's
trajectory is published to splice into the running one there (the adapter checks the
junction and every sample, as it checks any trajectory).

A session is the first put's ``session``; its ``seq`` must rise. While it tracks (a put within
its ``deadman``), another session's puts are ignored; once its deadman runs out the arm rests
where the last trajectory braked it (nothing need be sent: the brake was in it), and the same
session may go on, or another begin. ``stop``, an estop, a ``move`` (which takes over) or an
adapter's abort end the session for good: its later puts are ignored.

What the stream does not follow it says on ``<prefix>/<robot>/events``: ``{"event": "track",
"status": ...}``, once per status and reason a second at most (``repeated`` counts those not said).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
import uuid
from collections import Counter, OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from armd import solvers
from armd.errors import ArmdError, BadRequest
from armd.planning import JointState, Trajectory
from armd.planning.compiled import fit_motion
from armd.planning.online import track_step
from armd.robots import Robot
from armd.robots.types import FloatArray
from armd.solvers.world import compiled

from .state import Known, where_the_adapter_is
from .track_message import DEADMAN, TRACK_BYTES, TrackPut, parse, session_of

log = logging.getLogger(__name__)
RATE_HZ = 200.0  # [Hz] a stream's trajectories' samples (the adapters interpolate between them)
LEAD = 0.003  # [s] a cycle's trajectory takes over this far ahead of now, at the least (the way to the adapter) ...
MAX_LEAD = 0.05  # [s] ... more after one came late (a busy machine), up to this, and back down as they come on time
LEAD_DECAY = 0.995  # (a cycle's share of the extra lead kept: 2 s at 100 Hz)
MIN_PERIOD = 0.005  # [s] a cycle at most this often: faster puts are coalesced, the latest wins
STREAM_PRIORITY = 10  # SCHED_FIFO priority of a stream's thread (the adapters' loops run at 20)
SAY_EVERY = 1.0  # [s] each status and reason said at most this often
JOG_STEP = 0.1  # [s] the most a jogging put moves the tool's point on (a put after a gap does not jump)
GRIPPER_EVERY = 0.05  # [s] the gripper is sent at most this often
GRIPPER_STEP = 0.01  # ... and only when it changes by this much
PACE_PUTS = 4  # a moving goal's velocity: fitted to this many of the latest goals ...
PACE_WINDOW = 0.15  # [s] ... that came within this long (an older one: the goal rests)
CRUISE_PUTS = 2.0  # a moving goal is followed on at its pace for this many puts' time ...
CRUISE_RANGE = (0.02, 0.1)  # [s] ... within these (then braked, if no put came)
WAIT_RETRY = 0.02  # [s] a stream waiting for the arm to come to rest looks again this often
SENT_KEPT = 64  # the latest trajectories kept (a refusal comes back within a few cycles)
ENDED_KEPT = 4096  # sessions remembered as ended (their puts ignored)
Publish = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class _Sent:
    """A cycle's trajectory as published: the adapter runs it from ``t0`` (this clock)."""

    trajectory: Trajectory
    t0: float
    id: str
    braked: bool  # it stops short of the goal (at the deadman)
    goal: FloatArray
    after: str | None  # the id of the one it takes over from (None: it starts where the arm rests)


@dataclass
class _Jog:
    point: FloatArray  # [m] where the tool is sent
    pitch: float | None
    roll: float | None
    at: float  # when the last velocity put came


class Tracker:
    """One arm's tracking stream (thread-safe: puts come on Zenoh's threads, the cycles run
    on the tracker's own). ``publish`` puts a trajectory message, ``publish_gripper`` a
    gripper command, ``event`` an event; ``current`` says where the arm is (the service's book)."""

    def __init__(
        self,
        arm: Robot,
        *,
        publish: Publish,
        publish_gripper: Publish,
        event: Publish,
        current: Callable[[], Known],
        adapters: Callable[[], int] = lambda: 1,
    ) -> None:
        self.arm = arm
        self._publish = publish
        self._publish_gripper = publish_gripper
        self._event = event
        self._current = current
        self._adapters = adapters
        self._cv = threading.Condition()
        self._closed = False
        self._session: str | None = None
        self._deadman = DEADMAN
        self._last_seq = -1
        self._last_put = -math.inf
        self._said_deadman = True
        self._pending: TrackPut | None = None
        self._generation = 0  # one more each time a session begins or ends: a cycle of an older one is dropped
        self._next_cycle = 0.0
        self._ended: OrderedDict[str, str] = OrderedDict()  # session: why
        # the tracker thread's own (read and written by it alone, reset under the lock)
        self._goal: FloatArray | None = None
        self._branch: str | None = None
        self._jog: _Jog | None = None
        self._speed = 1.0
        self._prev: _Sent | None = None
        self._restart: JointState | None = None  # where an adapter said the arm is, refusing a trajectory
        self._sent: OrderedDict[str, _Sent] = OrderedDict()  # the latest published, by id (a refusal goes back)
        self.late = 0  # trajectories an adapter refused for coming after their time (a busy machine)
        self.lead = LEAD  # [s] how far ahead of now a cycle takes over
        self.rate_hz = RATE_HZ
        self.followed = 0  # cycles that followed a moving goal (the rest: to a goal at rest)
        self._gripper: tuple[float, float] | None = None  # (opening, when sent)
        self._goals: list[tuple[float, float, FloatArray]] = []  # (when it came, its time, the goal): the pace
        self._seen_generation = -1
        self._said: dict[tuple[str, str, Any], tuple[float, int]] = {}  # (status, reason, session): (said, unsaid)
        self.counts: Counter[tuple[str, str]] = Counter()  # what was to be said (said or not), by status and reason
        self.cycles = 0
        self._thread = threading.Thread(target=self._run, name=f"armd-track-{arm.name}", daemon=True)
        self._thread.start()

    # -- puts, on Zenoh's threads ------------------------------------------------------------

    def put(self, payload: bytes) -> None:
        """A put on the arm's track key: kept for the next cycle, or refused with an event."""
        now = time.monotonic()
        try:
            msg = parse(self.arm, payload)
        except BadRequest as e:
            self.say("bad_request", e.fields.get("field") or "payload", e.message, session=session_of(payload))
            return
        started = False
        with self._cv:
            if self._closed:
                return
            why = self._ended.get(msg.session)
            if why is not None:
                refusal: tuple[str, str, str] | None = ("ended", "ended", f"session {msg.session!r} ended ({why})")
            elif msg.session != self._session and now < self._last_put + self._deadman:
                refusal = ("busy", "busy", f"session {self._session!r} tracks {self.arm.name}; this one waits for it")
            elif msg.session == self._session and msg.seq <= self._last_seq:
                refusal = ("bad_request", "seq", f"seq {msg.seq} is not above the last one, {self._last_seq}")
            else:
                refusal = None
                if msg.session != self._session:
                    if self._session is not None:
                        self._end_locked(f"session {msg.session!r} took over after its deadman")
                    self._session, self._last_seq, started = msg.session, -1, True
                    self._deadman = msg.deadman if msg.deadman is not None else DEADMAN
                    self._generation += 1
                    self._pending = None
                self._last_seq, self._last_put, self._said_deadman = msg.seq, now, False
                self._pending = msg
                self._cv.notify()
        if refusal is not None:
            self.say(refusal[0], refusal[1], refusal[2], session=msg.session, seq=msg.seq)
        elif started:
            self.say(
                "started", "started", f"session {msg.session!r} tracks", session=msg.session, deadman=self._deadman
            )

    def end(self, reason: str) -> None:
        """End the session at once (a stop, an estop, a move): no trajectory of it is published
        from now on (the adapter's stop does the rest), its later puts are ignored."""
        with self._cv:
            session = self._session
            if session is None:
                return
            self._end_locked(reason)
        self.say("ended", reason, f"session {session!r} ended: {reason}", session=session)

    def _end_locked(self, reason: str) -> None:
        if self._session is not None:
            self._ended[self._session] = reason
            while len(self._ended) > ENDED_KEPT:
                self._ended.popitem(last=False)
        self._session, self._pending, self._last_put = None, None, -math.inf
        self._generation += 1
        self._cv.notify()

    def adapter_said(self, event: str, ident: str, reason: str, error: dict[str, Any] | None = None) -> None:
        """An adapter ``rejected`` or ``aborted`` trajectory ``ident``: if it is the stream's,
        a refusal goes back to the one it was to take over from (which the adapter still runs:
        the next cycle takes over from that one; from where the arm rests if none), and every
        one published after it is forgotten (the adapter refuses those too); an abort (a fault,
        a servo that could not follow) ends the session. A trajectory that came after its time
        (a busy machine) is only counted; any other refusal is said."""
        with self._cv:
            sent = self._sent.get(ident)
            if sent is None:
                return  # (not ours, or one after a refused one: gone back already)
            session = self._session
            if event == "aborted":
                self._end_locked(f"the adapter aborted it: {reason}")
            else:
                while self._sent:  # it and those after it
                    last_id, _ = self._sent.popitem(last=True)
                    if last_id == ident:
                        break
                there = where_the_adapter_is(self.arm, error)
                if there is not None:  # (not where it was thought to be: afresh, from where the adapter says)
                    self._prev, self._restart = None, there
                else:
                    self._prev = self._sent.get(sent.after) if sent.after is not None else None
                late = isinstance(error, dict) and isinstance(error.get("late"), (int, float))
                if late:
                    assert error is not None
                    self.late += 1
                    self.lead = min(max(2.0 * self.lead, self.lead + float(error["late"])), MAX_LEAD)
        if event == "aborted":
            self.say(
                "ended", "aborted", f"session {session!r} ended: the adapter aborted it: {reason}", session=session
            )
        elif late:
            log.debug("%s: a stream's trajectory came late: %s", self.arm.name, reason)
        else:
            self.say("rejected", "rejected", f"the adapter refused the stream's trajectory: {reason}", session=session)

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify()
        self._thread.join(timeout=5.0)

    # -- events -----------------------------------------------------------------------------

    def say(self, status: str, reason: str, message: str, **fields: Any) -> None:
        """An event ``{"event": "track", "status": ...}``, unless the same status and reason was
        said of the same session less than ``SAY_EVERY`` ago (then counted, and the count said
        with the next)."""
        now = time.monotonic()
        key = (status, reason, fields.get("session"))
        with self._cv:
            self.counts[(status, reason)] += 1
            last, unsaid = self._said.get(key, (-math.inf, 0))
            if now - last < SAY_EVERY:
                self._said[key] = (last, unsaid + 1)
                return
            self._said[key] = (now, 0)
            if len(self._said) > 256:
                self._said = {k: v for k, v in self._said.items() if now - v[0] < SAY_EVERY}
        extra = {k: v for k, v in fields.items() if v is not None}
        if unsaid:
            extra["repeated"] = unsaid
        try:
            self._event({"event": "track", "status": status, "reason": reason, "message": message, **extra})
        except Exception:  # (the session closing)
            log.debug("track event not published", exc_info=True)

    # -- the cycles, on the tracker's thread -------------------------------------------------

    def _run(self) -> None:
        ahead_of_requests(f"{self.arm.name}: its tracking stream")
        while True:
            with self._cv:
                while True:
                    if self._closed:
                        return
                    now = time.monotonic()
                    watching = self._session is not None and not self._said_deadman
                    expiry = self._last_put + self._deadman if watching else math.inf
                    deadman = now >= expiry
                    due = self._pending is not None and now >= self._next_cycle
                    if deadman or due:
                        break
                    until = min(expiry, self._next_cycle if self._pending is not None else math.inf)
                    self._cv.wait(min(until - now, 1.0))
                put = self._pending if due else None
                self._pending = None if due else self._pending
                self._said_deadman = self._said_deadman or deadman
                generation, session, deadline = self._generation, self._session, self._last_put + self._deadman
                if generation != self._seen_generation:  # a session began or ended: its goal and trajectory forgotten
                    self._seen_generation = generation
                    self._goal = self._branch = self._jog = self._prev = self._restart = None
                    self._gripper = None  # (a new session's gripper is sent, whatever the last one's was)
                    self._sent.clear()
                    self._speed = 1.0
                    self._goals = []
            if deadman:
                self.say(
                    "deadman",
                    "deadman",
                    f"no put for {self._deadman:g} s: {self.arm.name} brakes to rest",
                    session=session,
                )
                continue
            try:
                self._cycle(put, generation, session, deadline)
            except ArmdError as e:
                self.say("error", e.code, e.message, session=session)
            except Exception as e:  # a bug: said, logged, and the stream goes on (the arm brakes at the deadman)
                log.exception("%s: a tracking cycle failed", self.arm.name)
                self.say("error", "internal", f"internal error: {type(e).__name__}: {e}", session=session)

    def _cycle(self, put: TrackPut | None, generation: int, session: str | None, deadline: float) -> None:
        if put is not None and put.mode != "none":
            self._aim(put)
            if self._goal is not None:
                came = time.monotonic()
                stamp = put.time if put.time is not None else came
                goals = self._goals
                if goals and (stamp <= goals[-1][1] or (put.time is None) != (goals[-1][1] == goals[-1][0])):
                    goals = []  # (a time stamp that went back, or came or went: the pace afresh)
                self._goals = [*goals[-(PACE_PUTS - 1) :], (came, stamp, self._goal)]
        goal = self._goal
        if goal is None or session is None:
            return
        if self._adapters() == 0:  # (nothing would run it: said, and planned afresh once one is back)
            self.say("waiting", "no_adapter", f"no adapter drives {self.arm.name}: nothing is sent", session=session)
            with self._cv:
                self._prev = None
            return
        now = time.monotonic()
        prev = self._prev
        rate = self.rate_hz
        dt = 1.0 / rate
        splice: dict[str, Any] | None = None
        there = prev is not None and not prev.braked and np.array_equal(prev.goal, goal)
        if prev is not None and now - prev.t0 < prev.trajectory.duration:
            if there:
                return  # (on its way to the goal, where it rests: nothing to add)
            traj = prev.trajectory
            k = min(math.ceil((now - prev.t0 + self.lead) * rate - 1e-9), len(traj.times) - 1)
            start = JointState(traj.position[k], traj.velocity[k], traj.acceleration[k])
            splice, t0 = {"after": prev.id, "at": k * dt}, prev.t0 + k * dt
        elif prev is not None:  # (it has ended, by this clock: it may still settle at the adapter)
            if there:
                return  # (resting on the goal)
            traj = prev.trajectory
            start = JointState.at_rest(traj.position[-1].copy())
            splice, t0 = {"after": prev.id, "at": traj.duration}, now  # (at its end: the adapter starts it on arrival)
        else:
            known = self._current()
            restart, self._restart = self._restart, None
            if restart is not None and not restart.moving:
                known = Known(restart, "adapter", False)
            if known.moving:  # a stream starts from rest: looked at again shortly
                self.say(
                    "waiting", "moving", f"{self.arm.name} is moving: the stream starts once it rests", session=session
                )
                with self._cv:
                    if self._pending is None and self._generation == generation:
                        self._pending = TrackPut(session, -1, "none", goal)  # (the goal kept: aimed once)
                        self._next_cycle = now + WAIT_RETRY
                return
            start, t0 = JointState.at_rest(self.arm.limits.clip(known.state.position)), now
        pace, cruise, came = self._pace(now)
        cruise = max(cruise, 2.0 * self.lead)  # (the next cycle, late, still finds it moving)
        if pace is not None:  # (carried on to the trajectory's start)
            ahead = t0 - came
            pace = JointState(
                pace.position + pace.velocity * ahead + pace.acceleration * (ahead * ahead / 2),
                pace.velocity + pace.acceleration * ahead,
                pace.acceleration,
            )
        step = track_step(
            self.arm,
            start,
            goal,
            horizon=deadline - t0,
            speed=self._speed,
            rate_hz=rate,
            reference=pace,
            cruise=cruise,
        )
        traj = step.trajectory
        ident = uuid.uuid4().hex
        # (the samples' positions: what an adapter runs and checks; its velocities and the rest it
        # does not trust, and a third of the bytes to parse, a hundred times a second)
        msg: dict[str, Any] = {
            "robot": self.arm.name,
            "id": ident,
            "kind": "move",
            "path": "track",
            "track": session,
            "rate_hz": traj.rate_hz,
            "times": traj.times,  # (arrays: orjson writes them as they are, service.protocol.encode)
            "position": traj.position,
            "seq": put.seq if put is not None and put.mode != "none" else None,
        }
        if splice is not None:
            msg["splice"] = splice
        with self._cv:
            if self._generation != generation:
                return  # (ended meanwhile: a stop is under way)
            if self._prev is not prev:  # (an adapter's refusal went back meanwhile: planned again at once)
                if self._pending is None:
                    self._pending = TrackPut(session, -1, "none", goal)  # (the goal kept: aimed once)
                return
            self._publish(msg)
            self._prev = _Sent(
                step.trajectory, t0, ident, step.braked, goal.copy(), prev.id if splice and prev else None
            )
            self._sent[ident] = self._prev
            while len(self._sent) > SENT_KEPT:
                self._sent.popitem(last=False)
            self._next_cycle = now + MIN_PERIOD
            self.cycles += 1
            self.followed += step.followed
            self.lead = max(LEAD, self.lead * LEAD_DECAY)
        if step.hit is not None:
            self.say(
                "collision",
                "path",
                f"the way to the goal touches something ({step.hit.message}): the arm stops short",
                session=session,
                pair=list(step.hit.fields.get("pair") or ()),
            )

    def _pace(self, now: float) -> tuple[JointState | None, float, float]:
        """Where the goal is going: a parabola fitted (least squares) to the latest goals at
        their times (the puts' own ``time`` where they have one: a busy network or machine
        bunches their arrivals), its position, velocity and acceleration at the latest one (a
        line for two; None if it rests, or a goal is all there is), how long to follow it on,
        and when the latest one came."""
        goals = [g for g in self._goals if now - g[0] <= PACE_WINDOW]
        if len(goals) < 2:
            return None, 0.0, now
        t = np.array([g[1] for g in goals])
        q = np.array([g[2] for g in goals])
        span = float(t[-1] - t[0])
        if span <= 1e-4:
            return None, 0.0, now
        fit = np.empty((3, q.shape[1]))
        if not fit_motion(t - t[-1], q, 2 if len(goals) >= 3 else 1, fit):  # (least squares: one compiled call)
            return None, 0.0, now
        p, v, a = fit
        if not np.any(np.abs(v) > 1e-6):
            return None, 0.0, now
        interval = span / (len(goals) - 1)
        cruise = min(max(CRUISE_PUTS * interval, CRUISE_RANGE[0]), CRUISE_RANGE[1])
        return JointState(p, v, a), cruise, float(goals[-1][0])

    # -- goals ------------------------------------------------------------------------------

    def _aim(self, put: TrackPut) -> None:
        """The put's goal (``self._goal``), or the last one kept and the reason said."""
        if put.mode == "none":  # (a retry: the goal is kept)
            return
        if put.speed is not None:
            self._speed = put.speed
        if put.gripper is not None:
            self._grip(put.gripper)
        if put.mode == "joints":
            self._jog = None
            self._aim_joints(put)
        elif put.mode == "target":
            self._jog = None
            r = solvers.solve_ik(self.arm, put.value, approach=put.approach, roll=put.roll, seed=self._seed())
            self._take(r, put)
        else:
            self._aim_velocity(put)

    def _seed(self) -> FloatArray:
        if self._goal is not None:
            return self._goal
        return self.arm.limits.clip(self._current().state.position)

    def _aim_joints(self, put: TrackPut) -> None:
        q = put.value
        lim = self.arm.limits
        if not lim.contains(q):
            clipped = lim.clip(q)
            if not lim.contains(clipped):  # (a coupled limit: no nearest point as simple as a clip)
                self.say("unreachable", "limits", "the joints are outside the arm's limits: held", session=put.session)
                return
            j = int(np.argmax(np.abs(clipped - q)))
            self.say(
                "unreachable",
                "limits",
                f"joint {self.arm.joint_names[j]} at {q[j]:.4f} rad is beyond its limits: taken to {clipped[j]:.4f}",
                session=put.session,
                seq=put.seq,
            )
            q = clipped
        world = self.arm.collision
        contact = compiled(world).first_contact(q) if world is not None else None
        if contact is not None:
            self.say(
                "collision",
                "goal",
                f"the joints put {contact.first} and {contact.second} in contact: held short of them",
                session=put.session,
                seq=put.seq,
                pair=[contact.first, contact.second],
            )
            return
        self._goal = q.copy()

    def _aim_velocity(self, put: TrackPut) -> None:
        now = time.monotonic()
        jog = self._jog
        if jog is None:
            q = self._seed()
            jog = _Jog(
                self.arm.fk(q),
                self.arm.tool_pitch(q) if self.arm.chooses_pitch else None,
                self.arm.tool_roll(q),
                now,
            )
            self._jog = jog
        step = min(max(now - jog.at, 0.0), JOG_STEP)
        jog.at = now
        point = jog.point + put.value * step
        pitch = None if jog.pitch is None else _wrap(jog.pitch + put.pitch_rate * step)
        roll = None if jog.roll is None else _wrap(jog.roll + put.roll_rate * step)
        if np.array_equal(point, jog.point) and pitch == jog.pitch and roll == jog.roll and self._goal is not None:
            return
        r = solvers.solve_ik(self.arm, point, approach=pitch, roll=roll, seed=self._seed())
        if self._take(r, put) and self._goal is not None:
            q = self._goal
            jog.point = self.arm.fk(q)  # (where it got: a point beyond reach does not run away)
            jog.pitch = self.arm.tool_pitch(q) if jog.pitch is not None else None
            jog.roll = self.arm.tool_roll(q) if jog.roll is not None else None

    def _take(self, r: solvers.IKResult, put: TrackPut) -> bool:
        """The IK answer as the goal, kept on the stream's branch; False if none was taken."""
        if r.status == solvers.COLLISION:
            self.say(
                "collision",
                "goal",
                f"the target puts the arm in contact ({r.reason}): held short of it",
                session=put.session,
                seq=put.seq,
                pair=list(r.contact) if r.contact else None,
            )
            return False
        q, branch = r.q, r.branch
        if self._branch is not None and branch != self._branch and "numerical" not in (branch, self._branch):
            same = next((b for b in r.branches if b.name == self._branch), None)
            if same is None:
                self.say(
                    "unreachable",
                    "branch",
                    f"only the {branch} branch reaches the target; the stream stays on {self._branch}: held",
                    session=put.session,
                    seq=put.seq,
                )
                return False
            q, branch = same.q, same.name
        if r.status == solvers.UNREACHABLE:
            self.say(
                "unreachable",
                "reach",
                f"the target is out of reach ({r.reason}): the closest point, {r.position_error * 1e3:.1f} mm from it",
                session=put.session,
                seq=put.seq,
                position_error=r.position_error,
            )
        self._goal, self._branch = np.array(q, dtype=float), branch
        return True

    def _grip(self, opening: float) -> None:
        now = time.monotonic()
        last = self._gripper
        if last is not None and (abs(opening - last[0]) < GRIPPER_STEP or now - last[1] < GRIPPER_EVERY):
            return
        assert self.arm.gripper is not None  # (the put was refused otherwise)
        self._publish_gripper({"opening": opening, "pulse": self.arm.gripper.pulse(opening), "id": uuid.uuid4().hex})
        self._gripper = (opening, now)


def ahead_of_requests(what: str) -> None:
    """This thread ahead of ordinary threads and processes (SCHED_FIFO), where the system
    permits it: beside a guest's flood of IK batches, a stream's put took 11 ms (median) and
    37 ms (p99) to reach the arm, against 3 and 4 idle (bench/track.py --flood). Else as it is,
    said once in the log. ``what``: the thread, for the log."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(STREAM_PRIORITY))  # (0: this thread, on Linux)
        log.info("%s runs at real-time priority (SCHED_FIFO %d)", what, STREAM_PRIORITY)
    except (PermissionError, OSError, AttributeError) as e:
        log.info("%s runs at normal priority (no SCHED_FIFO: %s)", what, e)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


__all__ = ["TRACK_BYTES", "Tracker"]
