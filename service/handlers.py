"""The verbs: each takes a robot, a validated request object and its deadline, returns a
reply object.

No Zenoh here: :mod:`service.server` calls these and turns what they raise into error
replies. Every request is checked whole against its verb's shape (:mod:`service.protocol`:
unknown fields at every level, every number a finite JSON number of a sane size, fields that
exclude each other) before anything is solved, planned or published. Long work checks the
deadline between its stages, and a verb that publishes checks it once more just before
publishing: a request that overran has changed nothing. Once published, a command is
answered with success, whatever the clock says.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from armd import planning, solvers
from armd.errors import (
    ArmdError,
    BadRequest,
    BatchTooLarge,
    Busy,
    NoAdapter,
    NotReady,
    PositionUnknown,
    Rejected,
)
from armd.planning import JointState
from armd.robots import Robot
from armd.robots.collision import SIZES, Obstacle

from .deadline import Deadline
from .protocol import (
    DETECT,
    FK,
    GRIPPER,
    IK_BATCH,
    IK_ONE,
    MAX_OBSTACLES,
    MAX_SWEEPS,
    MOVE,
    NOTHING,
    PLAN,
    PROTOCOL_VERSION,
    SEQUENCE,
    WORLD,
    Limits,
    check,
    plain_point,
)
from .sensor_book import DISPUTE_HOLD, SensorBook
from .sequence import ABOVE, LIFT, SPEED, Sequence, check_distance, check_speed, sequence_point
from .sequence import steps as sequence_steps
from .state import StateBook, where_the_adapter_is

SENSOR_POLL = 0.05  # [s] how often detect looks for the sweeps it waits for
SENSOR_MARGIN = 0.1  # [s] of the deadline kept for the answer

Publish = Callable[[Robot, dict[str, Any]], Any]  # (a trajectory's: the id of the adapter that accepted it)
AdapterCount = Callable[[Robot], int]


class Handlers:
    def __init__(
        self,
        arms: Mapping[str, Robot],
        book: StateBook,
        limits: Limits,
        publish: Publish,
        adapters: AdapterCount,
        publish_gripper: Publish | None = None,
        publish_estop: Publish | None = None,
        sensor_book: SensorBook | None = None,
        end_tracking: Callable[[str, str], None] | None = None,
    ) -> None:
        self.arms = dict(arms)
        self.end_tracking = end_tracking or (lambda robot, reason: None)  # (a stop's, a move's: the stream ends)
        self.sensor_book = sensor_book
        self._stop_counts: dict[str, int] = {}  # per arm: stops seen (a pick or place under way ends at one)
        self._sequencing: set[str] = set()  # arms running a pick or place (one at a time)
        self.publish_gripper: Publish = publish_gripper or (lambda arm, msg: None)
        self.publish_estop: Publish = publish_estop or (lambda arm, msg: None)
        self.book = book
        self.limits = limits
        self.publish = publish
        self.adapters = adapters
        self._world_lock = threading.Lock()  # (world changes, one at a time; never on a stop's path)
        self._sequence_lock = threading.Lock()  # (stop counts and the arms sequencing: held for a few lines)
        # an arm's obstacles from robot.toml: those it has at its first world request (only
        # this verb changes the world)
        self._fixed: dict[str, frozenset[str]] = {}

    # -- read-only verbs -------------------------------------------------------------------

    def robots(self, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        check(NOTHING, req)
        arms = [{"name": a.name, "title": a.title, "joints": list(a.joint_names)} for a in self.arms.values()]
        return {"protocol": PROTOCOL_VERSION, "robots": arms, "limits": dataclasses.asdict(self.limits)}

    def info(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        check(NOTHING, req)
        known = self.book.current(arm)
        out = arm.describe()
        out.update(
            {
                "protocol": PROTOCOL_VERSION,
                "adapters": self.adapters(arm),
                "state": {
                    "source": known.source,
                    "moving": known.moving,
                    "homed": known.homed,
                    **known.state.to_dict(),
                },
            }
        )
        return out

    def fk(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        req = check(FK, req, arm.joint_names)
        q = arm.joint_vector(req["q"])
        pose = arm.pose(q)
        return {
            "q": q.tolist(),
            "position": pose.position.tolist(),
            "pitch": pose.pitch,
            "within_limits": arm.limits.contains(q),
        }

    def ik(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        point = plain_point(req)
        if point is not None:  # (the commonest request, checked in one pass: every option at its default)
            return solvers.solve_ik(arm, point).to_dict()
        if req.get("targets") is not None:
            if req.get("target") is not None:
                raise BadRequest("target and targets exclude each other: one target, or a batch", field="target")
            targets = req["targets"]
            if isinstance(targets, list) and len(targets) > self.limits.max_batch:  # before walking them
                raise BatchTooLarge(len(targets), self.limits.max_batch)
            req = check(IK_BATCH, req, arm.joint_names)
            return solvers.solve_ik_batch(
                arm,
                req["targets"],
                approach=req.get("approach"),
                seeds=req.get("seeds"),
                tolerance=req.get("tolerance", solvers.DEFAULT_TOLERANCE),
                check=deadline.check,
            ).to_dict()
        req = check(IK_ONE, req, arm.joint_names)
        seed = req.get("seed")
        if seed is None and _reads_on_the_arm(arm, req):  # converted where the arm is, never at neutral
            seed = self._present(arm, req).state.position
        return solvers.solve_ik(
            arm,
            req["target"],
            approach=req.get("approach"),
            seed=seed,
            tolerance=req.get("tolerance", solvers.DEFAULT_TOLERANCE),
            quantise=req.get("quantise", False),
            roll=req.get("roll"),
        ).to_dict()

    def plan(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        req = check(PLAN, req, arm.joint_names)
        start = req.get("start")
        if start is None and _reads_on_the_arm(arm, req):
            start = _at_the_limits(arm, self._present(arm, req).state)
        traj = self._plan(arm, req, start, deadline)
        return traj.to_dict()

    # -- verbs that move the arm --------------------------------------------------------------

    def move(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        req = check(MOVE, req, arm.joint_names)
        known = self._present(arm, req) if _reads_on_the_arm(arm, req) else self.book.current(arm)
        traj = self._plan(
            arm, req, _at_the_limits(arm, known.state), deadline
        )  # (a bad request is told so, adapter or not)
        if self.adapters(arm) == 0:
            raise NoAdapter(f"no adapter drives {arm.name}: nothing would execute the move", robot=arm.name)
        if not known.homed:
            raise PositionUnknown(
                f"{arm.name}'s adapter does not know where the arm is (its controller lost the "
                "position): home it or confirm its rest pose with `armd unlock` first",
                robot=arm.name,
            )
        msg = self._message(arm, traj, "move")
        goal = req["goal"]
        if isinstance(goal, Mapping) and isinstance(goal.get("target"), list):
            msg["target"] = goal["target"]  # the Cartesian target asked for (viewers draw it)
        deadline.check()  # the last moment to give up: after this the arm moves
        self.end_tracking(arm.name, "a move took over")  # (a stream in progress: the move replaces it)
        source = known.source
        try:
            adapter = self.publish(arm, msg)  # (once an adapter has accepted it)
        except Rejected as e:
            there = where_the_adapter_is(arm, e.fields.get("error"))
            if there is None:
                raise
            # The adapter's word on where the arm is beat the service's (its reports came late):
            # planned once more from there, and checked by the adapter again.
            traj = self._plan(arm, req, _at_the_limits(arm, there), deadline)
            msg = {**self._message(arm, traj, "move"), **({"target": msg["target"]} if "target" in msg else {})}
            deadline.check()
            adapter = self.publish(arm, msg)
            source = "adapter"
        self.book.commanded(arm.name, traj)
        return {
            "id": msg["id"],
            "adapter": adapter,
            "path": traj.path,
            "duration": traj.duration,
            "samples": len(traj.times),
            "start": traj.start.to_dict(),
            "goal": traj.position[-1].tolist(),
            "start_source": source,
        }

    def stop(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        """Never refused: not for lateness, not for a state outside the limits. The stop goes
        out on ``estop`` first, and every adapter brakes from its own state; the reply's
        duration and rest pose are the service's estimate from what it knows of the arm."""
        ident = uuid.uuid4().hex
        self.end_tracking(arm.name, "stop")  # (first: no stream trajectory goes out after the estop)
        self.publish_estop(arm, {"id": ident, "by": "service"})  # (first: before anything that could wait)
        self.note_stop(arm.name)
        try:  # (read after: a request a stop cannot read still stops the arm, and says so)
            check(NOTHING, req)
            unread = None
        except BadRequest as e:
            unread = e
        known = self.book.current(arm)
        try:
            traj = planning.plan_stop(arm, known.state, clamp=True)
        except ArmdError:  # (an estimate only: the adapters brake from their own states)
            traj = planning.plan_stop(arm, JointState.at_rest(arm.limits.clip(known.state.position)), clamp=True)
        self.book.commanded(arm.name, traj)
        out = {
            "id": ident,
            "duration": traj.duration,
            "adapters": self.adapters(arm),
            "rest": traj.position[-1].tolist(),
        }
        return out | unread_request(unread) if unread is not None else out

    def gripper(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        """Open (1) or close (0) the gripper, or anything between: published to the adapters."""
        opening: float = check(GRIPPER, req)["opening"]
        if arm.gripper is None:
            raise BadRequest(f"{arm.name} has no gripper", field="opening")
        pulse = arm.gripper.pulse(opening)  # validates the range
        if self.adapters(arm) == 0:
            raise NoAdapter(f"no adapter drives {arm.name}: nothing would move the gripper", robot=arm.name)
        deadline.check()
        ident = uuid.uuid4().hex
        self.publish_gripper(arm, {"opening": opening, "pulse": pulse, "id": ident})
        return {"opening": opening, "pulse": pulse, "id": ident}

    def note_stop(self, robot: str) -> None:
        """The arm was stopped (a ``stop``, an adapter's abort or estop): a pick or place under way ends."""
        with self._sequence_lock:
            self._stop_counts[robot] = self._stop_counts.get(robot, 0) + 1

    # -- sequences: pick and place -------------------------------------------------------------

    def pick(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        """Seed 000's grasp (:mod:`service.sequence`): open, above, descend, close, lift."""
        return self._sequence(arm, "pick", req, deadline)

    def place(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        """The grasp reversed: above, descend, open, rise."""
        return self._sequence(arm, "place", req, deadline)

    def _sequence(self, arm: Robot, verb: str, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        req = check(SEQUENCE, req, arm.joint_names)
        if arm.gripper is None:
            raise BadRequest(f"{arm.name} has no gripper to {verb} with", field="target")
        approach = req.get("approach", "perpendicular")
        if approach not in ("perpendicular", "parallel"):
            raise BadRequest(f"approach must be 'perpendicular' or 'parallel', got {approach!r}", field="approach")
        above = check_distance(req.get("above"), "above", ABOVE)
        lift = check_distance(req.get("lift"), "lift", LIFT)
        speed = check_speed(req.get("speed", SPEED))
        if self.adapters(arm) == 0:
            raise NoAdapter(f"no adapter drives {arm.name}: nothing would {verb}", robot=arm.name)
        on_arm = _reads_on_the_arm(arm, req)
        known = self._present(arm, req) if on_arm else self.book.current(arm)
        point = sequence_point(arm, req["target"], known.state.position if on_arm else None)
        with self._sequence_lock:
            stops = self._stop_counts.get(arm.name, 0)
            if arm.name in self._sequencing:
                raise Busy(f"{arm.name} is running a pick or place already: one at a time", robot=arm.name)
            self._sequencing.add(arm.name)
        asked = _SequenceAsked(verb, point, approach, above, lift, speed)
        try:
            return self._run_sequence(arm, asked, deadline, known.state, stops)
        finally:
            with self._sequence_lock:
                self._sequencing.discard(arm.name)

    def _run_sequence(
        self, arm: Robot, asked: _SequenceAsked, deadline: Deadline, state: Any, stops: int
    ) -> dict[str, Any]:
        """Check every step of ``asked`` from the arm's ``state``, then run them (the stop count
        ``stops`` as it was when the request came: a stop since ends it)."""
        verb = asked.verb

        def fresh() -> Deadline:
            return Deadline(time.monotonic(), self.limits.deadline)

        seq = Sequence(
            arm,
            sequence_steps(arm, verb, asked.point, asked.approach, asked.above, asked.lift),
            speed=asked.speed,
            plan=lambda r, start: planning.plan(
                arm, start, r["goal"], path=r["path"], speed=r["speed"], max_samples=self.limits.max_samples
            ),
            move=lambda r: self.move(arm, r, fresh()),
            gripper=lambda opening: self.gripper(arm, {"opening": opening}, fresh()),
            present=lambda: self.book.current(arm),
            stops=lambda: self._stop_counts.get(arm.name, 0),
            estop=lambda: self.publish_estop(arm, {"id": uuid.uuid4().hex, "by": "service"}),
            check=deadline.check,
        )
        seq.check_all(_at_the_limits(arm, state))  # every step, before anything moves
        if self._stop_counts.get(arm.name, 0) != stops:
            raise Rejected(f"{arm.name} was stopped while the {verb} was planned: nothing moved", robot=arm.name)
        deadline.check()
        target = [float(x) for x in asked.point]
        return {"verb": verb, "target": target, "approach": asked.approach, **seq.run(stops)}

    # -- what the sensors see ----------------------------------------------------------------

    def detect(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        """The objects the arm's scanners see (:mod:`solvers.detect`): in the last ``sweeps``
        complete sweeps of each (default 2: the seed's test of a stable object), waiting within
        the deadline for them if they have not come yet. Only readings the sensor book believes
        (:mod:`.sensor_book`: a live adapter's, in order, plausible); a sensor two publishers
        dispute is ``not_ready`` at once, naming them. The reply names the adapters whose
        readings it rests on (``adapters``)."""
        req = check(DETECT, req)
        sweeps = req.get("sweeps", 2)
        if sweeps != int(sweeps):
            raise BadRequest(f"sweeps must be a whole number in [1, {MAX_SWEEPS}], got {sweeps!r}", field="sweeps")
        n = int(sweeps)
        scanners = [s.name for s in arm.sensors.values() if s.mount == "scanner"]
        names = req.get("sensors", scanners)
        for name in names:
            if name not in arm.sensors or arm.sensors[name].mount != "scanner":
                raise BadRequest(
                    f"{name!r} is not a scanning sensor of {arm.name} (its scanners: {', '.join(scanners) or 'none'})",
                    field="sensors",
                )
        if not names:
            raise BadRequest(f"{arm.name} has no scanning sensor", field="sensors")
        if self.adapters(arm) == 0:
            raise NoAdapter(f"no adapter of {arm.name} is alive to read its sensors", robot=arm.name)
        book = self.sensor_book
        assert book is not None
        while True:
            read = {name: book.read(arm.name, name, n) for name in names}
            disputed = {name: r.disputed for name, r in read.items() if r.disputed}
            if disputed:  # (never an answer on readings two publishers may have mixed)
                ids = sorted({a for ids in disputed.values() for a in ids})
                raise NotReady(
                    f"{arm.name}'s {', '.join(disputed)} readings are disputed: two publishers under one adapter "
                    f"id, or two adapters ({', '.join(ids)}); none is used until one alone has published in order "
                    f"for {DISPUTE_HOLD:g} s. Ask again; if it lasts, someone else publishes on the sensors' keys",
                    robot=arm.name,
                    disputed=list(disputed),
                    adapters=ids,
                )
            got = {name: r.sweeps for name, r in read.items()}
            short = {name: len(s) for name, s in got.items() if len(s) < n}
            if not short:
                break
            if time.monotonic() + SENSOR_POLL > deadline.at - SENSOR_MARGIN:
                said = ", ".join(f"{k} {v}" for k, v in short.items())
                raise NotReady(
                    f"{arm.name}'s scanners have not swept {n} time(s) yet (complete sweeps: {said}); ask again, "
                    "or with a longer deadline",
                    robot=arm.name,
                )
            time.sleep(SENSOR_POLL)
        objects = solvers.detect(arm, got)
        return {
            "objects": [o.to_dict() for o in objects],
            "sweeps": n,
            "sensors": list(names),
            "adapters": sorted({r.adapter for r in read.values()}),  # (whose readings it rests on)
        }

    # -- the arm's world ---------------------------------------------------------------------

    def world(self, arm: Robot, req: Mapping[str, Any], deadline: Deadline) -> dict[str, Any]:
        """The arm's world: its floor and obstacles, listed (an empty request); obstacles added
        (``add``), removed by name (``remove``), the run-time ones all removed (``clear``), in
        that order, all or nothing. Obstacles of ``robot.toml`` are fixed. Plans and IK asked
        after the reply see the new world; the reply lists it, and what the arm, where the service
        knows it to be, touches in it now (``contacts``: plans from there are refused)."""
        req = check(WORLD, req)
        changing = bool(req.get("add") or req.get("remove") or req.get("clear"))
        with self._world_lock:
            model = arm.collision
            if model is None:
                if changing:
                    raise BadRequest(
                        f"{arm.name} has no collision model (its URDF's collision shapes could not be read): "
                        "it has no world to change",
                        field=next(k for k in ("add", "remove", "clear") if req.get(k)),
                    )
                return {"world": None, "fixed": [], "contacts": []}
            fixed = self._fixed.setdefault(arm.name, frozenset(o.name for o in model.obstacles))
            obstacles = [o for o in model.obstacles if o.name in fixed or not req.get("clear")]
            for i, name in enumerate(req.get("remove", [])):
                field = f"remove[{i}]"
                if name in fixed:
                    raise BadRequest(f"{field}: {name!r} is fixed in {arm.name}'s robot.toml", field=field)
                if not any(o.name == name for o in obstacles):
                    raise BadRequest(f"{field}: {arm.name}'s world has no obstacle {name!r}", field=field)
                obstacles = [o for o in obstacles if o.name != name]
            taken = set(model.links) - {o.name for o in model.obstacles} | {o.name for o in obstacles}
            for i, spec in enumerate(req.get("add", [])):  # (the links, the ground, the obstacles so far)
                deadline.check()
                obstacles.append(_obstacle(spec, f"add[{i}]", taken))
                taken.add(obstacles[-1].name)
            if len(obstacles) - len(fixed) > MAX_OBSTACLES:
                raise BadRequest(
                    f"at most {MAX_OBSTACLES} obstacles may be added to an arm's world, this would make "
                    f"{len(obstacles) - len(fixed)}",
                    field="add",
                )
            if changing:
                model = model.with_obstacles(obstacles)
                arm.collision = model  # (one assignment: a request sees the old world or the new one)
        here = self.book.current(arm).state.position
        return {
            "world": model.describe(),
            "fixed": sorted(fixed),
            "contacts": [[c.first, c.second] for c in model.contacts(here)],
        }

    # -- helpers ----------------------------------------------------------------------------

    def _present(self, arm: Robot, req: Mapping[str, Any]) -> Any:
        """Where ``arm`` is, as its adapter reports it, for a reading of a sensor on the arm (its
        point depends on the pose it was taken at); :class:`PositionUnknown` if no adapter
        reports one (the service's own guesses, neutral or the last trajectory, are not enough)."""
        known = self.book.current(arm)
        if known.source != "adapter":
            name = _reads_on_the_arm(arm, req)
            field = "seed" if "target" in req else "start"
            raise PositionUnknown(
                f"sensor {name!r} is on the arm: its reading is converted at the pose it was taken at, and no "
                f"adapter of {arm.name} reports where the arm is; give that joint vector ({field})",
                robot=arm.name,
                field=field,
            )
        return known

    def _plan(self, arm: Robot, req: Mapping[str, Any], start: object, deadline: Deadline) -> planning.Trajectory:
        """``req``: checked against its verb's shape already."""
        via = req.get("via", [])
        if len(via) > self.limits.max_waypoints:
            raise BadRequest(f"at most {self.limits.max_waypoints} waypoints", field="via")
        if start is None:
            start = _at_the_limits(arm, self.book.current(arm).state)
        path = req.get("path", "joint")
        speed = req.get("speed", 1.0)
        return planning.plan(
            arm,
            start,
            req["goal"],
            path=path,
            speed=speed,
            rate_hz=req.get("rate_hz"),
            via=via,
            max_samples=self.limits.max_samples,
            check=deadline.check,
        )

    @staticmethod
    def _message(arm: Robot, traj: planning.Trajectory, kind: str) -> dict[str, Any]:
        msg = traj.to_dict()
        msg.update({"id": uuid.uuid4().hex, "kind": kind})
        return msg


def _obstacle(spec: Mapping[str, Any], field: str, taken: set[str]) -> Obstacle:
    """An obstacle of the ``world`` verb (its shape checked already): its size's length, its
    name not taken by a link, the ground or another obstacle."""
    name, shape, size = spec["name"], spec["shape"], spec["size"]
    if name in taken:
        raise BadRequest(
            f"{field}.name: {name!r} is taken (by a link, the ground or another obstacle)", field=f"{field}.name"
        )
    want = SIZES[shape]
    if len(size) != want:
        what = {"box": "[x, y, z]", "sphere": "[radius]", "cylinder": "[radius, length]"}[shape]
        raise BadRequest(
            f"{field}.size: a {shape} takes {want} number(s) {what} [m], got {len(size)}", field=f"{field}.size"
        )
    return Obstacle(
        name,
        shape,
        tuple(float(x) for x in size),
        tuple(float(x) for x in spec["position"]),  # type: ignore[arg-type]
        tuple(float(x) for x in spec.get("rpy", (0.0, 0.0, 0.0))),  # type: ignore[arg-type]
    )


def _reads_on_the_arm(arm: Robot, req: Mapping[str, Any]) -> str | None:
    """The name of a sensor on the arm (``mount = "frame"``) whose reading ``req`` targets (its
    ``target``, ``goal`` or a via point), or None."""
    for g in [req.get("target"), req.get("goal"), *req.get("via", ())]:
        t = g.get("target") if isinstance(g, Mapping) and isinstance(g.get("target"), Mapping) else g
        if isinstance(t, Mapping) and "sensor" in t:
            sensor = arm.sensors.get(str(t["sensor"]))
            if sensor is not None and sensor.mount == "frame":
                return sensor.name
    return None


def _at_the_limits(arm: Robot, state: JointState) -> JointState:
    """Where the arm is, as a plan may start from it: a measured position a hair outside a box
    limit (a servo settled a count past a goal at its limit) taken at the limit. The state book
    keeps out reports farther off (``state.implausible``); a start a user gives is not clipped."""
    return JointState(arm.limits.clip(state.position), state.velocity, state.acceleration)


@dataclass(frozen=True)
class _SequenceAsked:
    """A pick or place as asked and checked: the verb, the point [m], the approach, the heights
    above and to lift [m], and the speed."""

    verb: str
    point: Any
    approach: str
    above: float
    lift: float
    speed: float


def unread_request(error: ArmdError) -> dict[str, Any]:
    """What a stop's reply says of a request it could not read (the arm was stopped all the
    same): ``warning``, and ``unread``, the error the request would have had."""
    return {
        "warning": f"the request was not read ({error.message}): the arm was stopped all the same",
        "unread": error.to_dict(),
    }
