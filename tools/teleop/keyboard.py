"""The keyboard: a jog in a terminal (curses), as a source of the teleoperation loop
(:mod:`.stream`).

Keys move the tool point forward and back, left and right (the arm's own directions:
:func:`.frames.heading`), up and down, turn its pitch and its roll (:mod:`.jog`), open and close
the gripper, and change the speed; space stops the arm (the ``stop`` verb), ``q`` quits. The
screen shows where the tool is (the arm's state, ``<prefix>/<robot>/state``, through the arm's
FK) and what the service said of the stream: why a key does nothing (a limit, out of reach, the
floor: its events ``unreachable``, ``collision`` ...).

A terminal says when a key is pressed, never when it is let go: it sends the key again and
again while it is held (its repeats), after a first delay (X's is 660 ms, most desktops' 500 ms),
then some 30 times a second. A key counts as held from its press for ``first`` (0.7 s: past the
first delay, so that the tool does not stop between the press and the first repeat) and, once
it repeats, until ``repeat`` (0.1 s) after its latest repeat. A tap therefore moves the tool for
``first`` (a slower speed makes a smaller nudge). A terminal repeats only the key pressed last:
one key at a time; the key of the other way on the same axis lets go of the first at once.
"""

from __future__ import annotations

import contextlib
import curses
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import orjson
import zenoh

from armd.clients.track import TrackEvent
from armd.robots import Robot

from .jog import Axes, Jog
from .stream import Put, Quit, Step, Stop

FIRST = 0.7  # [s] a key counts as held this long after its press (the terminal's first repeat comes by then)
REPEAT = 0.1  # [s] ... and this long after each repeat (they come every 30-40 ms)
DRAW_EVERY = 0.1  # [s] the screen is drawn again this often
SAID_FOR = 5.0  # [s] what was said stays on the screen this long

AXES = ("forward", "left", "up", "pitch", "roll")  # (Axes's, in order)
# key: (axis, direction)
MOVES: dict[int, tuple[str, int]] = {
    curses.KEY_UP: ("forward", 1),
    ord("w"): ("forward", 1),
    curses.KEY_DOWN: ("forward", -1),
    ord("s"): ("forward", -1),
    curses.KEY_LEFT: ("left", 1),
    ord("a"): ("left", 1),
    curses.KEY_RIGHT: ("left", -1),
    ord("d"): ("left", -1),
    curses.KEY_PPAGE: ("up", 1),
    ord("r"): ("up", 1),
    curses.KEY_NPAGE: ("up", -1),
    ord("f"): ("up", -1),
    ord("i"): ("pitch", 1),
    ord("k"): ("pitch", -1),
    ord("l"): ("roll", 1),
    ord("j"): ("roll", -1),
}
OPEN, CLOSE, STOP, QUIT = ord("o"), ord("c"), ord(" "), ord("q")
FASTER, SLOWER = (ord("+"), ord("=")), (ord("-"), ord("_"))
HELP = (
    "w s, up down: forward back    a d, left right: left right    r f, PgUp PgDn: up down",
    "i k: pitch up down    j l: roll    o c: gripper open close    + -: faster slower",
    "space: stop    q: quit    (a key counts as held while the terminal repeats it: one at a time)",
)


@dataclass
class _Key:
    pressed: float  # [s] when it was first pressed
    last: float  # [s] its latest repeat (or the press)
    repeated: bool


class Held:
    """Which keys are held, from their presses and repeats (module docstring): ``first`` [s]
    after a press, ``repeat`` [s] after a repeat."""

    def __init__(self, first: float = FIRST, repeat: float = REPEAT) -> None:
        self.first = first
        self.repeat = repeat
        self._keys: dict[Any, _Key] = {}

    def press(self, key: Any, now: float) -> None:
        """``key`` came at ``now`` [s]: a repeat if it is held, else a new press."""
        k = self._keys.get(key)
        if k is not None and self._holds(k, now):
            k.last, k.repeated = now, True
        else:
            self._keys[key] = _Key(now, now, False)

    def release(self, key: Any) -> None:
        self._keys.pop(key, None)

    def clear(self) -> None:
        self._keys.clear()

    def held(self, now: float) -> set[Any]:
        """The keys held at ``now`` [s] (those let go are forgotten)."""
        for key in [key for key, k in self._keys.items() if not self._holds(k, now)]:
            del self._keys[key]
        return set(self._keys)

    def _holds(self, k: _Key, now: float) -> bool:
        return now - k.last <= (self.repeat if k.repeated else self.first)


class ArmState:
    """The arm's latest state (``<prefix>/<robot>/state``), as its adapter publishes it."""

    def __init__(self, session: zenoh.Session, prefix: str, robot: str) -> None:
        self.position: list[float] | None = None
        self.source = ""
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(f"{prefix}/{robot}/state", self._on_state)

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            msg = orjson.loads(sample.payload.to_bytes())
            position = [float(x) for x in msg["position"]]
        except (orjson.JSONDecodeError, KeyError, TypeError, ValueError):
            return
        with self._lock:
            self.position, self.source = position, str(msg.get("source", ""))

    def latest(self) -> tuple[list[float] | None, str]:
        with self._lock:
            return self.position, self.source

    def close(self) -> None:
        with contextlib.suppress(zenoh.ZError):  # (the session closed first)
            self._sub.undeclare()


class Keyboard:
    """The keyboard on curses window ``screen``, jogging ``robot`` (the follower's model) whose
    state ``state`` follows; ``first`` and ``repeat`` [s]: :class:`Held`'s."""

    name = "the keyboard"

    def __init__(
        self, screen: Any, robot: Robot, state: ArmState, *, first: float = FIRST, repeat: float = REPEAT
    ) -> None:
        self.screen = screen
        self.robot = robot
        self.state = state
        self.jog = Jog(robot)
        self.held = Held(first, repeat)
        self.active = False  # putting (from the first key; not after a stop until the next)
        self.doing = "press a key to jog"
        self.last_put: Put | None = None
        self._said: list[tuple[float, str]] = []  # (when, what): the loop's lines and the service's events
        self._drawn_at = -math.inf
        self._shown: list[str] = []
        screen.nodelay(True)
        screen.keypad(True)
        with contextlib.suppress(curses.error):  # (a terminal that cannot hide it)
            curses.curs_set(0)

    # -- what the loop tells it ---------------------------------------------------------------

    def note(self, line: str) -> None:
        """A line of the loop's (a lost source, a stop refused), shown for ``SAID_FOR``."""
        self._said.append((time.monotonic(), line))
        del self._said[:-20]

    def event(self, e: TrackEvent) -> None:
        """An event of the service's (why the tool does not go where a key sends it)."""
        if e.status != "started":
            self.note(f"{e.status}: {e.message}")

    # -- the source ----------------------------------------------------------------------------

    def poll(self) -> Step:
        now = time.monotonic()
        stop = False
        while True:
            ch = self.screen.getch()
            if ch == -1:
                break
            if ch == QUIT:
                return Quit()
            if ch == STOP:
                stop = True
                self.held.clear()
            elif ch in MOVES:
                axis, sign = MOVES[ch]
                self.held.release((axis, -sign))  # (the other way on this axis lets go at once)
                self.held.press((axis, sign), now)
                self.active = True
            elif ch in (OPEN, CLOSE):
                self.jog.grip(1.0 if ch == OPEN else 0.0)
                self.active = True
            elif ch in FASTER:
                self.jog.faster()
            elif ch in SLOWER:
                self.jog.slower()
        held = self.held.held(now)
        axes = Axes(*(float(sum(s for a, s in held if a == axis)) for axis in AXES))
        step: Step = None
        if stop:
            self.active = False
            self.doing = "stopped (space): press a key to jog again"
            step = Stop()
        elif self.active:
            self.doing = ", ".join(f"{a} {'+' if s > 0 else '-'}" for a, s in sorted(held)) or "holding still"
            step = self.last_put = self.jog.put(axes)
        if stop or now - self._drawn_at >= DRAW_EVERY:
            self.draw(now)
        return step

    def close(self) -> None:
        self.state.close()

    # -- the screen ----------------------------------------------------------------------------

    def draw(self, now: float) -> None:
        self._drawn_at = now
        said = [line for t, line in self._said if now - t <= SAID_FOR]
        shown = said[-1] if said else ""
        position, source = self.state.latest()
        if position is None or len(position) != self.robot.nq:
            where = "no state from the arm yet (is its adapter running?)"
        else:
            pose = self.robot.pose(position)
            p = pose.position
            roll = self.robot.tool_roll(position)
            where = (
                f"x {p[0]:+.3f}  y {p[1]:+.3f}  z {p[2]:+.3f} m   pitch {math.degrees(pose.pitch):+6.1f} deg"
                + (f"   roll {math.degrees(roll):+6.1f} deg" if roll is not None else "")
                + f"   ({source})"
            )
        jog = self.jog
        grip = "not set" if jog.gripper is None else f"{jog.gripper:.2f}"
        lines = [
            f"armd teleop {self.robot.name}: the keyboard",
            "",
            f"tool   {where}",
            f"jog    {jog.linear:g} m/s, {jog.angular:g} rad/s" + (f"   gripper {grip}" if jog.has_gripper else ""),
            f"now    {self.doing}",
            f"said   {shown}",
            "",
            *(f"keys   {h}" if k == 0 else f"       {h}" for k, h in enumerate(HELP)),
        ]
        if lines[3:6] != self._shown:  # (what the operator did, or was told: the whole screen drawn afresh)
            self._shown = lines[3:6]
            self.screen.clearok(True)
        self.screen.erase()
        height, width = self.screen.getmaxyx()
        for row, line in enumerate(lines[:height]):
            with contextlib.suppress(curses.error):  # (a terminal too small: what fits)
                self.screen.addnstr(row, 0, line, max(width - 1, 0))
        self.screen.refresh()
