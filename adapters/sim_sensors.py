"""The simulator's range sensors: a world of objects on the floor, each sensor's beam cast into
it, its model's output (the datasheet's curve and noise, robots/sensor_models.toml), a
scanner's servo sweeping; each reading published on ``<prefix>/<robot>/sensors/<name>`` as a
real sensor adapter would.

The beam is a ray (the Sharp sensors' beam is a few degrees wide: an object's edges are seen a
little sooner, which this does not model). It meets the floor (``[world] ground``, else 0) and
the objects: upright cylinders (``size`` [radius, height]), boxes turned about z (``size`` [x, y,
z], ``yaw``) and spheres (``size`` [radius]), each standing on the floor at ``position`` [x,
y]. A scanner reads, turns its servo one ``sweep_step`` and reads again, reversing at each end
of its ``sweep``; a sensor on the arm reads along its frame where the simulated arm is. Each
reads once a measurement period (its model's, over the time scale, but no more than 100 times a
real second).

A reading (JSON):

- ``sensor``, ``model``, ``time`` [s, the epoch], ``adapter`` (its id), ``seq`` (the sensor's
  readings numbered 1, 2, ...: the service believes them in that order);
- ``volts`` [V]: the sensor's output, noise included;
- ``range`` [m]: what that output says by the model's curve, or null (nothing in range);
- ``bearing`` [rad]: a scanner's servo angle when it read (null for a sensor on the arm);
- ``sweep``: a scanner's sweep count (one more at each reversal), ``direction`` +1 or -1.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armd.errors import ArmdError, BadRequest
from armd.robots import Robot, Servo
from armd.robots.sensors import RangeSensor, models

from .sensor_stream import Numbering, Sweep, reading
from .trajectory_message import FloatArray

SHAPES = {"cylinder": 2, "box": 3, "sphere": 1}  # each shape's size: how many numbers
MIN_PERIOD = 0.01  # [s] real time between two readings of a sensor, at the least (a fast time scale's cap)


@dataclass(frozen=True)
class FloorObject:
    """An object standing on the floor at ``position`` [x, y] [m] (base frame)."""

    name: str
    shape: str
    size: tuple[float, ...]
    position: tuple[float, float]
    yaw: float = 0.0
    z: float = 0.0  # [m] its bottom above the floor (0: standing on it; more: carried by the gripper)

    @classmethod
    def of(cls, spec: Mapping[str, Any], where: str) -> FloorObject:
        """From ``{"name", "shape", "size", "position", "yaw"}``; :class:`BadRequest` naming what is wrong."""
        if not isinstance(spec, Mapping) or set(spec) - {"name", "shape", "size", "position", "yaw"}:
            raise BadRequest(f"{where}: an object is {{name, shape, size, position, yaw}}", field=where)
        shape = spec.get("shape")
        if shape not in SHAPES:
            raise BadRequest(f"{where}.shape must be one of {', '.join(SHAPES)}, got {shape!r}", field=f"{where}.shape")
        size, pos = spec.get("size"), spec.get("position")
        if not _numbers(size, SHAPES[shape]) or any(x <= 0 for x in size):  # type: ignore[union-attr]
            raise BadRequest(
                f"{where}.size: a {shape} takes {SHAPES[shape]} positive numbers [m]", field=f"{where}.size"
            )
        if not _numbers(pos, 2):
            raise BadRequest(f"{where}.position must be [x, y] [m] on the floor", field=f"{where}.position")
        yaw = spec.get("yaw", 0.0)
        if not _numbers([yaw], 1):
            raise BadRequest(f"{where}.yaw must be a number [rad]", field=f"{where}.yaw")
        return cls(str(spec.get("name", where)), str(shape), tuple(map(float, size)), (pos[0], pos[1]), float(yaw))  # type: ignore[index, arg-type]

    def holds(self, point: FloatArray, ground: float, slack: float = 0.01) -> bool:
        """Whether ``point`` [m] (a gripper's) is within the object, give or take ``slack``."""
        rel = point - np.array([*self.position, ground + self.z])
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x, y = c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1]
        if not -slack <= rel[2] <= self.height + slack:
            return False
        if self.shape == "box":
            return abs(x) <= self.size[0] / 2 + slack and abs(y) <= self.size[1] / 2 + slack
        return math.hypot(x, y) <= self.size[0] + slack

    @property
    def height(self) -> float:
        return {
            "cylinder": self.size[1] if len(self.size) > 1 else 0.0,
            "box": self.size[-1],
            "sphere": 2 * self.size[0],
        }[self.shape]

    def hit(self, origin: FloatArray, direction: FloatArray, ground: float) -> float:
        """How far along the ray (``direction`` a unit vector) it first meets this object [m], or
        inf; 0 from inside it."""
        if self.holds(origin, ground, slack=0.0):
            return 0.0
        cx, cy = self.position
        ground = ground + self.z
        if self.shape == "sphere":
            r = self.size[0]
            oc = origin - np.array([cx, cy, ground + r])
            b = float(oc @ direction)
            disc = b * b - (float(oc @ oc) - r * r)
            if disc < 0:
                return math.inf
            t = -b - math.sqrt(disc)
            return t if t >= 0 else (-b + math.sqrt(disc) if -b + math.sqrt(disc) >= 0 else math.inf)
        # into the object's own frame: turned by -yaw about z, its base centre at the origin
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rel = origin - np.array([cx, cy, ground])
        o = np.array([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2]])
        d = np.array([c * direction[0] + s * direction[1], -s * direction[0] + c * direction[1], direction[2]])
        if self.shape == "box":
            half = np.array([self.size[0] / 2, self.size[1] / 2, self.size[2] / 2])
            lo, hi = np.array([-half[0], -half[1], 0.0]), np.array([half[0], half[1], self.size[2]])
            return _slab(o, d, lo, hi)
        r, h = self.size
        best = math.inf
        a = d[0] ** 2 + d[1] ** 2
        if a > 1e-15:  # the side
            b = o[0] * d[0] + o[1] * d[1]
            disc = b * b - a * (o[0] ** 2 + o[1] ** 2 - r * r)
            if disc >= 0:
                for t in sorted(((-b - math.sqrt(disc)) / a, (-b + math.sqrt(disc)) / a)):
                    if t >= 0 and 0.0 <= o[2] + t * d[2] <= h:
                        best = min(best, t)
                        break
        if abs(d[2]) > 1e-15:  # the top and the bottom
            for z in (h, 0.0):
                t = (z - o[2]) / d[2]
                if t >= 0 and (o[0] + t * d[0]) ** 2 + (o[1] + t * d[1]) ** 2 <= r * r:
                    best = min(best, t)
        return best


def _numbers(v: object, n: int) -> bool:
    return (
        isinstance(v, (list, tuple))
        and len(v) == n
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    )


def _slab(o: FloatArray, d: FloatArray, lo: FloatArray, hi: FloatArray) -> float:
    """Where a ray first meets an axis-aligned box (or inf)."""
    t0, t1 = -math.inf, math.inf
    for k in range(3):
        if abs(d[k]) < 1e-15:
            if not lo[k] <= o[k] <= hi[k]:
                return math.inf
            continue
        a, b = (lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    if t1 < max(t0, 0.0):
        return math.inf
    return t0 if t0 >= 0 else t1


def objects_of(specs: object, where: str = "objects") -> list[FloorObject]:
    """A list of object specs, checked (names distinct)."""
    if not isinstance(specs, list):
        raise BadRequest(f"{where} must be a list of objects", field=where)
    out = [FloorObject.of(x, f"{where}[{k}]") for k, x in enumerate(specs)]
    names = [o.name for o in out]
    if len(set(names)) != len(names):
        raise BadRequest(f"{where}: object names must differ, got {names}", field=where)
    return out


class SimulatedSensors:
    """``robot``'s range sensors in a world of ``objects``: :meth:`run` publishes a reading of
    each every measurement period (its model's, over ``time_scale``), ``pose()`` giving the
    simulated arm's joint vector, until ``stop`` is set."""

    def __init__(
        self,
        robot: Robot,
        objects: Sequence[FloorObject],
        publish: Callable[[str, bytes], None],
        pose: Callable[[], FloatArray],
        *,
        adapter: str = "",
        time_scale: float = 1.0,
        seed: int | None = None,
    ) -> None:
        self.robot = robot
        self.objects = list(objects)
        self.publish = publish
        self.pose = pose
        self.adapter = adapter
        self.time_scale = time_scale
        world = robot.collision
        ground = world.ground if world is not None and world.ground is not None else 0.0
        self.ground = float(ground)
        self.rng = np.random.default_rng(seed)
        self.sensors = [s for s in robot.sensors.values() if s.curve is not None]
        self._sweeps = {s.name: Sweep(s) for s in self.sensors if s.mount == "scanner" and s.sweep is not None}
        self._numbers = Numbering()
        self._lock = threading.Lock()

    def distance(self, origin: FloatArray, direction: FloatArray) -> float:
        """How far the first thing a beam meets is [m] (inf: nothing)."""
        best = math.inf
        if direction[2] < -1e-12 and origin[2] > self.ground:  # the floor
            best = (self.ground - origin[2]) / direction[2]
        for o in self.objects:
            best = min(best, o.hit(origin, direction, self.ground))
        return best

    def volts(self, sensor: RangeSensor, bearing: float | None, q: FloatArray | None) -> float:
        """``sensor``'s output [V] now, noise included: a scanner at ``bearing``, a sensor on the
        arm with the arm at ``q``."""
        curve = sensor.curve
        assert curve is not None
        with self._lock:
            origin, direction = self.robot.sensor_ray(sensor.name, bearing or 0.0, q)
            return curve.volts(self.distance(origin, direction)) + float(self.rng.normal(0.0, curve.noise_volts))

    def read(self, sensor: RangeSensor) -> dict[str, Any]:
        """One reading of ``sensor`` now, its scanner's servo then turned a step."""
        sweep = self._sweeps.get(sensor.name)
        q = None if sensor.mount == "scanner" else self.pose()
        volts = self.volts(sensor, None if sweep is None else sweep.bearing, q)
        msg = reading(sensor, volts, self.adapter, self._numbers.next(sensor.name), sweep)
        if sweep is not None:
            sweep.step()
        return msg

    def set_objects(self, objects: Sequence[FloorObject]) -> None:
        with self._lock:
            self.objects = list(objects)

    def run(self, stop: threading.Event) -> None:
        """Read every sensor every period until ``stop`` is set."""
        if not self.sensors:
            return
        period = min(m.period for m in models().values() if m.name in {s.model for s in self.sensors})
        while not stop.wait(max(period / self.time_scale, MIN_PERIOD)):
            for s in self.sensors:
                try:
                    self.publish(s.name, json.dumps(self.read(s)).encode())
                except Exception:  # (the session closed under it: the adapter is going)
                    return


class AnalogWorld:
    """The voltages on an SSC-32U's analog inputs from ``robot``'s wired sensors (``pin``) in a
    world of ``objects``: the SSC-32 emulator's ``analog`` (``emulator.analog = world.volts``).

    A scanner looks along its servo's angle as the board outputs it (``pulse`` of its channel);
    a sensor on the arm along its frame, the arm where the board's pulses put it. A Sharp sensor
    measures over a period (its model's, 38.3 ms for the GP2D12) and puts out the result at its
    end, held until the next one is done: here the output over a period is what the beam met
    in the middle of the period before. Noise as the simulator's (its model's, per measurement)."""

    def __init__(self, robot: Robot, objects: Sequence[FloorObject], seed: int | None = None) -> None:
        self.robot = robot
        self.world = SimulatedSensors(robot, objects, lambda name, payload: None, lambda: robot.neutral, seed=seed)
        self.pins = {s.pin: s for s in self.world.sensors if s.pin is not None}
        self.channels = [a.channel for a in robot.actuators.actuators if isinstance(a, Servo)]  # (the SSC-32's)
        self._held: dict[str, tuple[int, float]] = {}  # pin -> (measurement number, its output [V])

    def set_objects(self, objects: Sequence[FloorObject]) -> None:
        self.world.set_objects(objects)

    def volts(self, pin: str, t: float, pulse: Callable[[int, float], float]) -> float:
        """The voltage on ``pin`` at time ``t`` [s, the board's clock] (0: nothing wired to it)."""
        sensor = self.pins.get(pin)
        if sensor is None or sensor.curve is None:
            return 0.0
        period = sensor.curve.period
        k = math.floor(t / period)
        held = self._held.get(pin)
        if held is not None and held[0] == k:
            return held[1]
        start = (k - 0.5) * period  # (the measurement whose output holds now: the period before's, at its middle)
        if sensor.servo is not None:
            bearing: float | None = float(sensor.servo.to_angle(np.array(pulse(sensor.servo.channel, start))))
            q = None
        else:
            bearing = None
            pulses = np.array([pulse(ch, start) for ch in self.channels])
            try:
                q = self.robot.actuators.joints_from_commands(pulses, tol=np.inf) if np.all(pulses > 0) else None
            except ArmdError:  # (a linkage's servo where the linkage cannot be)
                q = None
            if q is None:
                return 0.0  # (the arm's servos not driven yet, or nowhere: where it looks is not known)
        v = self.world.volts(sensor, bearing, q)
        self._held[pin] = (k, v)
        return v
