"""A bus-servo arm moved by hand, its torque off: its calibration measured (``armd
calibrate``) and its motion recorded (``armd record``).

Both open the bus themselves (no adapter may be running on the port), ping every servo (a
silent one is named), turn every torque off (the arm falls limp: support it) and read the
servos in sync reads, as fast as the bus answers. A lost reply is skipped (a reply garbled
is read again at once); no whole reading for ``LOST_FOR`` is a :class:`ControllerFault` naming
the servos that answer no ping. The torque stays
off when they end: ``armd adapter`` turns it on again where the arm is.

Calibration (:func:`calibrate`), step by step, each step a prompt answered with Enter:

1. the reference pose, every joint at 0 rad: each servo's ``zero``, its count there;
2. each joint nudged in its positive direction: the servo's ``direction``, the sign of its
   count's change (a joint that moves less than ``NUDGE`` is asked again, then refused);
3. every joint through its whole range: each servo's ``range``, the least and most counts
   seen (a reading that jumps by half a turn says the range crosses the servo's 0/4095 point:
   refused);
4. a gripper on the bus, closed, then open: its ``closed`` and ``open`` counts.

What it measured is checked against the arm (:func:`armd.robots.calibration.apply_tables`:
the joint limits must map inside each range) before anything is written.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from armd.errors import BadRequest, ControllerFault
from armd.planning.recording import Recording
from armd.robots import BusServo, Robot
from armd.robots import calibration as robots_calibration

from .base import actuators_of
from .bus_servo import Bus, Reading, ping_all, silent_servos, sync_read
from .trajectory_message import FloatArray

log = logging.getLogger(__name__)

NUDGE = 0.05  # [rad] the least a nudged joint must turn to show its direction
LIMP = "Hold the arm: its servos are about to let go (torque off). Then press Enter"
STILL_READS = 5  # readings whose median is a pose held still
NUDGE_TRIES = 3  # prompts for a joint that did not move before it is refused
LOST_FOR = 2.0  # [s] how long the reads may lose a reply before the bus is a fault (a hand is slow)


class HandGuided:
    """``robot``'s servos on ``bus``, every one answering, then (once ``ready()`` returns: the
    operator holds the arm) its torque off."""

    def __init__(self, robot: Robot, bus: Bus, ready: Callable[[], None]) -> None:
        self.robot = robot
        self.bus = bus
        self.servos = actuators_of(robot, BusServo, bus.name)
        self.gripper_id = robot.gripper.channel if robot.gripper is not None else None
        self.ids = [s.id for s in self.servos] + ([self.gripper_id] if self.gripper_id is not None else [])
        ping_all(bus, robot, self.servos)
        ready()
        for i in self.ids:
            bus.set_torque(i, False)
        self._whole_at = time.monotonic()  # [s] the last whole reading (or the start)

    def read(self) -> dict[int, Reading] | None:
        """One sync read of every servo (:func:`sync_read`); None if a reply was lost (no whole
        reading for ``LOST_FOR``: :class:`ControllerFault` naming the servos that answer no
        ping, else those the reads missed)."""
        got, _ = sync_read(self.bus, self.ids)
        now = time.monotonic()
        missing = [i for i in self.ids if i not in got]
        if not missing:
            self._whole_at = now
            return got
        if now - self._whole_at > LOST_FOR:
            quiet = silent_servos(self.bus, missing)
            raise ControllerFault(
                f"servo id {', '.join(map(str, quiet or missing))} "
                + (
                    f"does not answer on {self.bus.port}"
                    if quiet
                    else f"replies lost for {LOST_FOR} s on {self.bus.port}"
                )
                + ": check its cable and its power"
            )
        return None

    def still(self) -> dict[int, float]:
        """Each servo's count [counts], the median of a few readings (the arm held still)."""
        reads: list[dict[int, Reading]] = []
        while len(reads) < STILL_READS:
            got = self.read()
            if got is not None:
                reads.append(got)
        return {i: float(np.median([r[i].position for r in reads])) for i in self.ids}

    def joints(self, got: dict[int, Reading]) -> FloatArray:
        """The joint vector [rad] a reading says (by the arm's map: its calibration, if applied)."""
        counts = np.array([got[s.id].position for s in self.servos], dtype=float)
        return self.robot.actuators.joints_from_commands(counts, tol=np.inf)

    def opening(self, got: dict[int, Reading]) -> float | None:
        """The gripper's opening in [0, 1] a reading says (None: no gripper on the bus)."""
        g = self.robot.gripper
        if g is None or self.gripper_id is None:
            return None
        return float(np.clip((got[self.gripper_id].position - g.closed) / (g.open - g.closed), 0.0, 1.0))


def calibrate(
    robot: Robot, bus: Bus, ask: Callable[[str], None], say: Callable[[str], None]
) -> tuple[dict[str, tuple[float, int, tuple[float, float]]], tuple[float, float] | None]:
    """Measure ``robot``'s calibration on ``bus`` with the operator: ``ask(prompt)`` returns when
    they have done what it says (pressed Enter), ``say`` tells them the rest. Returns
    ``({actuator: (zero, direction, (low, high))}, gripper (closed, open) or None)``, checked
    against the arm's limits (else :class:`RobotFileError` naming the servo). ``bus`` is closed
    at the end, whatever happens."""
    try:
        amap = robot.actuators
        if not amap.linear:
            behind = ", ".join(amap.names[k] for k in amap.linkages)
            raise BadRequest(
                f"calibrating by hand takes servos that turn with one joint each; {behind} turns through a "
                "linkage: write its zero and direction in calibration.toml",
                field="robot",
            )
        arm = HandGuided(robot, bus, lambda: ask(LIMP))
        servos = arm.servos
        say(f"{robot.name}: {len(arm.ids)} servos answer on {bus.port}; their torque is off")
        ask("Put the arm at its reference pose, every joint at 0 rad (the arm's README shows it), then press Enter")
        ref = arm.still()
        a_ref = amap.M @ np.zeros(robot.nq) + amap.b  # [rad] each actuator's angle at the reference pose
        direction: dict[int, int] = {}
        for k, s in enumerate(servos):
            j = int(np.argmax(np.abs(amap.M[k])))  # (the joint that turns this servo)
            name = robot.joint_names[j]
            sign = int(np.sign(amap.M[k, j]))
            for _ in range(NUDGE_TRIES):
                before = arm.still()
                ask(f"Turn {name} a little (10 to 30 degrees) the way a positive angle turns it, then press Enter")
                after = arm.still()
                moved = (after[s.id] - before[s.id]) / s.counts_per_rad  # [rad] this servo's turn
                others = {o.name: abs(after[o.id] - before[o.id]) / o.counts_per_rad for o in servos if o.id != s.id}
                if abs(moved) >= NUDGE:
                    direction[s.id] = sign * (1 if moved > 0 else -1)
                    say(f"{s.name}: direction {direction[s.id]:+d} (turned {abs(moved):.2f} rad)")
                    break
                more = max(others, key=lambda n: others[n]) if others else None
                hint = f"; {more} turned {others[more]:.2f} rad" if more and others[more] >= NUDGE else ""
                say(f"{s.name} turned {abs(moved):.3f} rad, less than {NUDGE} rad{hint}: again")
            else:
                raise BadRequest(
                    f"{s.name} (servo id {s.id}) did not turn by {NUDGE} rad in {NUDGE_TRIES} tries: "
                    "is its horn fixed to the link?",
                    field=s.name,
                )
        lows, highs = _sweep(arm, ask)
        zero = {s.id: ref[s.id] - direction[s.id] * float(a_ref[k]) * s.counts_per_rad for k, s in enumerate(servos)}
        values = {s.name: (float(round(zero[s.id])), direction[s.id], (lows[s.id], highs[s.id])) for s in servos}
        gripper = None
        if arm.gripper_id is not None:
            ask("Close the gripper fully, then press Enter")
            closed = arm.still()[arm.gripper_id]
            ask("Open the gripper fully, then press Enter")
            opened = arm.still()[arm.gripper_id]
            gripper = (closed, opened)
        tables: dict[str, Any] = {n: {"zero": z, "direction": d, "range": list(r)} for n, (z, d, r) in values.items()}
        if gripper is not None:
            tables["gripper"] = {"closed": gripper[0], "open": gripper[1]}
        robots_calibration.apply_tables(robot, tables, "the measured calibration")
        return values, gripper
    finally:
        bus.close()


def _sweep(arm: HandGuided, ask: Callable[[str], None]) -> tuple[dict[int, float], dict[int, float]]:
    """Each servo's least and most count while the operator sweeps every joint (read at the
    bus's rate meanwhile), refused if a reading jumps by half a turn (the 0/4095 point crossed)."""
    lows = {s.id: math.inf for s in arm.servos}
    highs = {s.id: -math.inf for s in arm.servos}
    done = threading.Event()
    failed: list[BaseException] = []

    def watch() -> None:
        last: dict[int, int] = {}
        try:
            while not done.is_set():
                got = arm.read()
                if got is None:
                    continue
                for s in arm.servos:
                    c = got[s.id].position
                    if s.id in last and abs(c - last[s.id]) > s.counts_per_rev / 2:
                        raise BadRequest(
                            f"{s.name} (servo id {s.id}) jumped from {last[s.id]} to {c} counts: its range "
                            "crosses the servo's 0/4095 point; set the servo's offset so it does not",
                            field=s.name,
                        )
                    last[s.id] = c
                    lows[s.id], highs[s.id] = min(lows[s.id], c), max(highs[s.id], c)
        except BaseException as e:  # (told when the sweep ends)
            failed.append(e)

    reader = threading.Thread(target=watch, name="armd-calibrate-sweep", daemon=True)
    reader.start()
    try:
        ask("Move every joint slowly through its whole range, to both ends, then press Enter")
    finally:
        done.set()
        reader.join()
    if failed:
        raise failed[0]
    return lows, highs


def record(
    robot: Robot,
    bus: Bus,
    stop: threading.Event,
    *,
    seconds: float | None = None,
    say: Callable[[str], None],
    ready: Callable[[], None],
) -> Recording:
    """The arm's motion by hand, every joint and the gripper read at the bus's rate, from when
    ``ready()`` returns (the operator holds the arm; the torque then goes off) until ``stop`` is
    set (or ``seconds`` have passed). ``bus`` is closed at the end, whatever happens."""
    try:
        arm = HandGuided(robot, bus, ready)
        say(f"{robot.name}: recording; the servos' torque is off: move the arm by hand")
        t0 = time.monotonic()
        times: list[float] = []
        position: list[FloatArray] = []
        opening: list[float] = []
        while not stop.is_set() and (seconds is None or time.monotonic() - t0 < seconds):
            got = arm.read()
            now = time.monotonic()
            if got is None:
                continue
            times.append(now - t0)
            position.append(arm.joints(got))
            g = arm.opening(got)
            if g is not None:
                opening.append(g)
        if len(times) < 2:
            raise ControllerFault(f"the recording of {robot.name} has {len(times)} reading(s): nothing to replay")
        return Recording(
            robot=robot.name,
            joints=tuple(robot.joint_names),
            times=np.array(times),
            position=np.array(position),
            gripper=np.array(opening) if opening else None,
        )
    finally:
        bus.close()
