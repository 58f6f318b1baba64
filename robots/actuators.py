"""Actuator maps: joint vector -> actuator angles -> servo pulses or stepper micro-steps, and back.

An actuator angle is a linear function of the joint vector, ``a = M q + b`` (one row per
actuator), or the angle of a servo behind a four-bar linkage (:mod:`robots.linkages`: the desk4
minor-arm servo). A plain servo has a single 1 in its row; a mirrored pair (the SG5-UT shoulder)
is two rows on the same joint whose pulses run in opposite directions; an ideal parallelogram
would be the row ``(0, 1, 1)``. Pulses and steps are functions of ``a``, never of ``q``
directly. A command outside an actuator's range is an error
(:class:`~robots.errors.ActuatorRangeError`), never silently clamped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from armd.errors import ActuatorMapError, ActuatorRangeError, BadRequest

from .linkages import FourBar
from .types import FloatArray

IntArray = NDArray[np.int64]

_TOL = 1e-7  # [rad] numerical slack on actuator angle ranges (a servo pulse step is ~1.6e-3 rad)


@dataclass(frozen=True)
class Servo:
    """A hobby servo on a pulse-width controller (SSC-32 channel).

    ``pulse = centre_pulse + direction * (angle - centre_angle) * us_per_rad`` [us].
    """

    name: str
    channel: int
    centre_pulse: float
    centre_angle: float
    direction: int
    us_per_rad: float
    pulse_range: tuple[float, float]
    angle_range: tuple[float, float]

    kind = "servo"
    unit = "us"

    def to_command(self, angle: FloatArray) -> FloatArray:
        """Pulse width [us] (unrounded) for actuator angle(s) [rad]."""
        return self.centre_pulse + self.direction * (angle - self.centre_angle) * self.us_per_rad

    def to_angle(self, command: FloatArray) -> FloatArray:
        """Actuator angle [rad] for pulse width(s) [us]."""
        return self.centre_angle + self.direction * (command - self.centre_pulse) / self.us_per_rad

    @property
    def command_range(self) -> tuple[float, float]:
        return self.pulse_range

    @property
    def resolution(self) -> float:
        """One command quantum (1 us) as an angle [rad]."""
        return 1.0 / self.us_per_rad


@dataclass(frozen=True)
class Stepper:
    """A stepper motor on a step/dir driver, positioned in micro-steps from its zero.

    ``steps = round(angle * gear * microsteps * full_steps_per_rev / (2 pi))``.
    ``axis`` is the controller's axis letter (GRBL ``X``, ``Y``, ``Z``).
    """

    name: str
    axis: str
    full_steps_per_rev: int
    microsteps: int
    gear: float
    angle_range: tuple[float, float]

    kind = "stepper"
    unit = "steps"

    @property
    def steps_per_rad(self) -> float:
        return self.gear * self.microsteps * self.full_steps_per_rev / (2.0 * math.pi)

    @property
    def steps_per_degree(self) -> float:
        """Micro-steps per degree of actuator angle: GRBL's ``$100..$102`` setting."""
        return self.steps_per_rad * math.pi / 180.0

    @property
    def step_angle(self) -> float:
        """One micro-step as an angle [rad] (seed 002 Table II, in radians)."""
        return 1.0 / self.steps_per_rad

    @property
    def resolution(self) -> float:
        return self.step_angle

    def to_command(self, angle: FloatArray) -> FloatArray:
        """Micro-steps (unrounded) for actuator angle(s) [rad]."""
        return angle * self.steps_per_rad

    def to_angle(self, command: FloatArray) -> FloatArray:
        """Actuator angle [rad] for micro-step count(s)."""
        return command / self.steps_per_rad

    @property
    def command_range(self) -> tuple[float, float]:
        lo, hi = self.angle_range
        return (math.ceil(lo * self.steps_per_rad - _TOL), math.floor(hi * self.steps_per_rad + _TOL))


@dataclass(frozen=True)
class BusServo:
    """A serial bus servo that reports where it is (Feetech STS/SCS, Dynamixel X series),
    positioned in encoder counts on its bus ``id``.

    ``counts = zero + direction * angle * counts_per_rev / (2 pi)``: ``zero`` is the count at
    actuator angle 0 and ``direction`` the sign of the count against the angle (the arm's
    calibration, kept in ``calibration.toml`` beside the arm's folder, overrides both and the
    range); ``count_range`` is the counts the servo may be commanded to (its angle limits).
    """

    name: str
    id: int
    counts_per_rev: int
    zero: float
    direction: int
    count_range: tuple[float, float]
    angle_range: tuple[float, float]

    kind = "bus_servo"
    unit = "counts"

    @property
    def counts_per_rad(self) -> float:
        return self.counts_per_rev / (2.0 * math.pi)

    @property
    def resolution(self) -> float:
        """One count as an angle [rad]."""
        return 1.0 / self.counts_per_rad

    def to_command(self, angle: FloatArray) -> FloatArray:
        """Counts (unrounded) for actuator angle(s) [rad]."""
        return self.zero + self.direction * angle * self.counts_per_rad

    def to_angle(self, command: FloatArray) -> FloatArray:
        """Actuator angle [rad] for count(s)."""
        return self.direction * (command - self.zero) / self.counts_per_rad

    @property
    def command_range(self) -> tuple[float, float]:
        return self.count_range


Actuator = Servo | Stepper | BusServo


@dataclass(frozen=True)
class Gripper:
    """The gripper: an actuator that is not a joint of the chain. Pulses [us] on an SSC-32
    channel, or counts of the bus servo whose id is ``channel``."""

    channel: int
    closed: float
    open: float

    def pulse(self, opening: float) -> int:
        """Pulse [us] (or counts) for ``opening`` in [0, 1] (0 closed, 1 open)."""
        if isinstance(opening, bool) or not (
            isinstance(opening, (int, float)) and math.isfinite(opening) and 0.0 <= opening <= 1.0
        ):  # (True is an int to Python, not to JSON)
            raise BadRequest(f"gripper opening must be a number in [0, 1], got {opening!r}", field="opening")
        return round(self.closed + opening * (self.open - self.closed))


class ActuatorMap:
    """``a = M q + b``, or a linkage's angle, and each actuator's command conversion,
    vectorised over samples.

    ``M`` has shape (k, n): k actuators, n joints. ``linkages`` maps an actuator's row to the
    :class:`~robots.linkages.FourBar` that gives its angle; that row of ``M`` holds the
    linkage's slope at mid-range (which joints move the servo, and roughly how much: code that
    needs exact values takes :meth:`angles` and :meth:`jacobian`; :attr:`slopes` bounds them).
    The linear rows must determine every joint that no linkage drives (full column rank there),
    and not involve a driven joint, so that :meth:`joints_from_commands` recovers ``q`` from what
    the hardware reports: the linear rows first, then each linkage's inverse.
    """

    def __init__(
        self,
        actuators: tuple[Actuator, ...],
        M: FloatArray,
        b: FloatArray,
        linkages: dict[int, FourBar] | None = None,
    ) -> None:
        self.actuators = actuators
        self.M = np.asarray(M, dtype=float)
        self.b = np.asarray(b, dtype=float)
        self.linkages = dict(linkages or {})
        n = self.M.shape[1]
        self._lin = [k for k in range(len(actuators)) if k not in self.linkages]
        driven = {link.driven for link in self.linkages.values()}
        self._free = [j for j in range(n) if j not in driven]
        if (
            len(driven) < len(self.linkages)
            or any(link.input in driven for link in self.linkages.values())
            or np.any(self.M[np.ix_(self._lin, sorted(driven))])
        ):
            raise ValueError("each linkage must drive its own joint, which no linear row and no linkage's input is")
        self._pinv = np.linalg.pinv(self.M[np.ix_(self._lin, self._free)])
        # |da/dq| over the joints' range, at its largest and smallest: M's for the linear rows
        self.slopes = np.abs(self.M)
        self.gentlest = np.abs(self.M)
        for k, link in self.linkages.items():
            self.slopes[k], self.gentlest[k] = link.steepest, link.gentlest
        self._angle_lo = np.array([a.angle_range[0] for a in actuators])
        self._angle_hi = np.array([a.angle_range[1] for a in actuators])
        self.names = tuple(a.name for a in actuators)
        # every actuator's command is affine in its angle: command = gain * angle + bias
        self._bias = np.array([float(a.to_command(np.array(0.0))) for a in actuators])
        self._gain = np.array([float(a.to_command(np.array(1.0))) for a in actuators]) - self._bias
        self._cmd_lo = np.array([a.command_range[0] for a in actuators], dtype=float)
        self._cmd_hi = np.array([a.command_range[1] for a in actuators], dtype=float)

    def with_actuators(self, actuators: tuple[Actuator, ...]) -> ActuatorMap:
        """The same map (rows, linkages) over other actuators' conversions (a calibration)."""
        return ActuatorMap(actuators, self.M, self.b, self.linkages)

    def __len__(self) -> int:
        return len(self.actuators)

    @property
    def linear(self) -> bool:
        """Whether every actuator angle is ``M q + b`` exactly (no linkage)."""
        return not self.linkages

    @property
    def ranges(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, float]:
        """What :meth:`commands` computes with, for compiled loops that must agree with it:
        angle range (lo, hi) [rad], command = rint(gain * angle + bias), command range
        (lo, hi), and the slack on angle ranges [rad]."""
        return (self._angle_lo, self._angle_hi, self._gain, self._bias, self._cmd_lo, self._cmd_hi, _TOL)

    def angles(self, q: FloatArray) -> FloatArray:
        """Actuator angles [rad] of joint vector(s) ``q``: shape (n,) -> (k,), (m, n) -> (m, k).
        A linkage that cannot be assembled at ``q`` gives NaN."""
        q = np.asarray(q, dtype=float)
        a = q @ self.M.T + self.b
        for k, link in self.linkages.items():
            a[..., k] = link.angle(q)
        return a

    def jacobian(self, q: FloatArray) -> FloatArray:
        """``da/dq`` at joint vector(s) ``q``: (n,) -> (k, n), (m, n) -> (m, k, n)."""
        q = np.asarray(q, dtype=float)
        J = np.broadcast_to(self.M, (*q.shape[:-1], *self.M.shape)).copy()
        for k, link in self.linkages.items():
            J[..., k, :] = link.gradient(q)
        return J

    def command_rates(self, q: FloatArray, v: FloatArray) -> FloatArray:
        """Each actuator's command rate (pulses [us/s], steps/s) at joint position(s) ``q`` moving
        at ``v`` [rad/s]: ``gain * J(q) v``."""
        return np.einsum("...kn,...n->...k", self.jacobian(q), np.asarray(v, dtype=float)) * self._gain

    def rate_bounds(self, velocity: FloatArray, acceleration: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Each actuator angle's speed [rad/s] and acceleration [rad/s^2] bounds, anywhere in the
        joints' range, for joints within ``velocity`` and ``acceleration``: ``|da/dq| v`` and
        ``|da/dq| a``, plus for a linkage its curvature's share ``v' |d2a/dq2| v``."""
        speed = self.slopes @ velocity
        accel = self.slopes @ acceleration
        for k, link in self.linkages.items():
            accel[k] += velocity @ link.curvature @ velocity
        return speed, accel

    def command_values(self, q: FloatArray) -> FloatArray:
        """Commands (pulse [us] or micro-steps) for joint vector(s) ``q``, unrounded and unchecked:
        where a controller that interpolates between commands is at a point between them."""
        return self.angles(q) * self._gain + self._bias

    def commands(self, q: FloatArray) -> IntArray:
        """Integer commands (pulse [us] or micro-steps) for joint vector(s) ``q``.

        Raises :class:`ActuatorRangeError` naming the first actuator that would leave its
        range; nothing is clamped.
        """
        q = np.asarray(q, dtype=float)
        if not np.all(np.isfinite(q)):
            raise BadRequest("joint positions must be finite to map them to actuator commands", field="q")
        a = self.angles(q)
        if not np.all(np.isfinite(a)):  # (a linkage that cannot be assembled there)
            row, j = np.argwhere(~np.isfinite(np.atleast_2d(a)))[0]
            act = self.actuators[j]
            err = ActuatorRangeError(act.name, math.nan, act.angle_range, "rad")
            err.message = f"actuator {act.name!r}: its linkage cannot be assembled at these joint positions"
            err.args = (err.message,)
            raise err
        self.check_angles(a)
        cmds = np.rint(a * self._gain + self._bias)
        bad = (cmds < self._cmd_lo) | (cmds > self._cmd_hi)
        if np.any(bad):
            row, j = np.argwhere(np.atleast_2d(bad))[0]
            act = self.actuators[j]
            value = float(np.atleast_2d(cmds)[row, j])
            raise ActuatorRangeError(act.name, value, (float(self._cmd_lo[j]), float(self._cmd_hi[j])), act.unit)
        return cmds.astype(np.int64)

    def check_angles(self, a: FloatArray) -> None:
        """Raise :class:`ActuatorRangeError` if any actuator angle [rad] leaves its range."""
        bad = (a < self._angle_lo - _TOL) | (a > self._angle_hi + _TOL)
        if np.any(bad):
            flat = np.atleast_2d(bad)
            row, col = np.argwhere(flat)[0]
            act = self.actuators[col]
            value = float(np.atleast_2d(a)[row, col])
            raise ActuatorRangeError(act.name, value, act.angle_range, "rad")

    def angles_from_commands(self, commands: FloatArray | IntArray) -> FloatArray:
        """Actuator angles [rad] from commands (pulses [us] or micro-steps)."""
        c = np.asarray(commands, dtype=float)
        if c.shape[-1] != len(self.actuators):
            raise BadRequest(
                f"expected {len(self.actuators)} actuator commands ({', '.join(self.names)}), got {c.shape[-1]}",
                field="commands",
            )
        return (c - self._bias) / self._gain

    def joints_from_commands(self, commands: FloatArray | IntArray, tol: float | None = None) -> FloatArray:
        """Joint vector(s) [rad] that the given commands put the arm in (hardware read-back).

        The linear rows give the joints no linkage drives, redundant actuators (a mirrored pair)
        reconciled by least squares: if they disagree by more than ``tol`` [rad] (default: two
        command quanta) this raises :class:`ActuatorMapError`. Each linkage's inverse then gives
        its driven joint; a reading the linkage cannot take raises :class:`ActuatorMapError`
        whatever ``tol``.
        """
        a = self.angles_from_commands(commands)
        lin, free = self._lin, self._free
        q = np.zeros((*a.shape[:-1], self.M.shape[1]))
        q[..., free] = (a[..., lin] - self.b[lin]) @ self._pinv.T
        residual = np.abs(q[..., free] @ self.M[np.ix_(lin, free)].T + self.b[lin] - a[..., lin])
        limit = tol if tol is not None else 2.0 * max(act.resolution for act in self.actuators)
        if np.any(residual > limit):
            j = lin[int(np.argmax(np.max(np.atleast_2d(residual), axis=0)))]
            raise ActuatorMapError(
                f"actuator readings disagree: {self.actuators[j].name} is {float(np.max(residual)):.3g} rad "
                "from what the other actuators imply",
                actuator=self.actuators[j].name,
            )
        for k, link in self.linkages.items():
            q[..., link.driven] = link.joint(a[..., k], q)
            bad = ~np.isfinite(q[..., link.driven])
            if np.any(bad):
                value = float(np.atleast_1d(a[..., k])[np.argmax(np.atleast_1d(bad))])
                raise ActuatorMapError(
                    f"actuator {self.actuators[k].name!r} reads {value:.4g} rad, an angle its linkage cannot "
                    "take with the other joints where they are",
                    actuator=self.actuators[k].name,
                )
        return q

    def quantise(self, q: FloatArray) -> FloatArray:
        """The joint vector(s) the hardware actually reaches for ``q``: commands, then back."""
        return self.joints_from_commands(self.commands(q), tol=np.inf)
