"""A gamepad: the jog of the keyboard (:mod:`.jog`) on sticks and triggers, read through
python-evdev (the ``gamepad`` extra), as a source of the teleoperation loop (:mod:`.stream`).

The layout is the Linux gamepad's (the kernel's ``Documentation/input/gamepad.rst``: an Xbox
or a PlayStation pad reads the same):

- left stick (``ABS_X``, ``ABS_Y``): forward and back, left and right;
- right stick (``ABS_RY``, ``ABS_RX``): the tool's pitch, its roll;
- triggers (``ABS_RZ`` right, ``ABS_Z`` left; or their buttons ``BTN_TR2``, ``BTN_TL2``): up, down;
- bumpers (``BTN_TR``, ``BTN_TL``): the gripper open, closed;
- the D-pad up and down (``ABS_HAT0Y``, or ``BTN_DPAD_UP``, ``BTN_DPAD_DOWN``): faster, slower;
- the east button (``BTN_EAST``: B, or the circle): stop (the ``stop`` verb); a stick or a
  trigger pushed then moves nothing until it has been let go.

A stick within its dead zone (``DEAD_ZONE`` of its travel, or the device's own ``flat`` if
larger) is at rest; beyond, its travel is scaled from the dead zone's edge to its end, so that
the tool starts from a crawl. A pad that goes (unplugged, out of range) is :class:`~.stream.Lost`:
nothing more is put until it is back (looked for again every ``RETRY``), in a new session.

The mapping (:class:`PadMap`: events in, axes and commands out) needs no device: it is what the
tests drive (no ``/dev/uinput`` there); :class:`EvdevPad` is the device.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from armd.errors import BadRequest

from .jog import Axes, Jog
from .stream import Lost, Step, Stop

log = logging.getLogger(__name__)

DEAD_ZONE = 0.15  # of a stick's half travel (a trigger's whole): at rest within it
RETRY = 0.5  # [s] a pad that went is looked for again this often

# evdev's names (the Linux gamepad's): an axis and the jog's axis it moves, and which way
STICKS = {"ABS_X": ("left", -1.0), "ABS_Y": ("forward", -1.0), "ABS_RX": ("roll", 1.0), "ABS_RY": ("pitch", -1.0)}
TRIGGERS = {"ABS_RZ": ("up", 1.0), "ABS_Z": ("up", -1.0)}
BUTTONS = {
    "BTN_EAST": "stop",
    "BTN_TR": "open",
    "BTN_TL": "close",
    "BTN_DPAD_UP": "faster",
    "BTN_DPAD_DOWN": "slower",
}
TRIGGER_BUTTONS = {"BTN_TR2": ("up", 1.0), "BTN_TL2": ("up", -1.0)}
HAT = "ABS_HAT0Y"  # the D-pad's vertical: -1 up (faster), 1 down (slower)
EV_KEY, EV_ABS = 1, 3  # the kernel's event types (linux/input-event-codes.h)


def evdev() -> Any:
    """python-evdev, or :class:`BadRequest` saying how to install it."""
    try:
        return importlib.import_module("evdev")
    except ImportError as e:
        raise BadRequest(f"armd teleop --gamepad needs python-evdev: pip install 'armd[gamepad]' ({e})") from None


@dataclass(frozen=True)
class Travel:
    """An axis's ``low`` and ``high`` values and its ``flat`` (the device's dead zone)."""

    low: int
    high: int
    flat: int = 0


class PadMap:
    """A pad's events (``type``, ``code``, ``value``: evdev's) as the jog's axes and commands.
    ``travel``: each axis's, by code (a stick's or a trigger's; :meth:`EvdevPad.travel`);
    ``at``: where each is now (a pad opened with a stick pushed)."""

    def __init__(self, travel: dict[int, Travel], at: dict[int, int] | None = None) -> None:
        codes = evdev().ecodes.ecodes
        self.travel = travel
        self._sticks = {codes[n]: m for n, m in STICKS.items() if n in codes}
        self._triggers = {codes[n]: m for n, m in TRIGGERS.items() if n in codes}
        self._buttons = {codes[n]: m for n, m in BUTTONS.items() if n in codes}
        self._trigger_buttons = {codes[n]: m for n, m in TRIGGER_BUTTONS.items() if n in codes}
        self._hat = codes[HAT]
        self._values: dict[int, float] = {}  # by code: a stick's in [-1, 1], a trigger's in [0, 1], after the dead zone
        self._pressed: set[int] = set()
        for code, value in (at or {}).items():
            self.feed(EV_ABS, code, value)

    def feed(self, type_: int, code: int, value: int) -> str | None:
        """One event: a command (``stop``, ``open``, ``close``, ``faster``, ``slower``) or None."""
        if type_ == EV_ABS:
            if code == self._hat:
                return "faster" if value < 0 else "slower" if value > 0 else None
            travel = self.travel.get(code)
            if travel is not None and (code in self._sticks or code in self._triggers):
                self._values[code] = _scaled(value, travel, stick=code in self._sticks)
            return None
        if type_ == EV_KEY:
            if value == 0:
                self._pressed.discard(code)
                return None
            if value == 1:  # (2: the kernel's auto-repeat of a held button: not a new press)
                self._pressed.add(code)
                return self._buttons.get(code)
        return None

    def axes(self) -> Axes:
        """Where the sticks, the triggers and the trigger buttons put the jog now."""
        out = dict.fromkeys(("forward", "left", "up", "pitch", "roll"), 0.0)
        for code, (axis, sign) in (*self._sticks.items(), *self._triggers.items()):
            out[axis] += sign * self._values.get(code, 0.0)
        for code, (axis, sign) in self._trigger_buttons.items():
            if code in self._pressed:
                out[axis] += sign
        return Axes(**{k: min(max(v, -1.0), 1.0) for k, v in out.items()})


def _scaled(value: int, travel: Travel, stick: bool) -> float:
    """An axis's value as a fraction of its travel (a stick's from its middle, in [-1, 1]; a
    trigger's from its low end, in [0, 1]), zero within its dead zone, scaled from its edge."""
    span = float(travel.high - travel.low)
    if span <= 0:
        return 0.0
    if stick:
        x = 2.0 * (value - travel.low) / span - 1.0
        dead = max(DEAD_ZONE, 2.0 * travel.flat / span)
    else:
        x = (value - travel.low) / span
        dead = max(DEAD_ZONE, travel.flat / span)
    x = min(max(x, -1.0), 1.0)
    if abs(x) <= dead:
        return 0.0
    return (abs(x) - dead) / (1.0 - dead) * (1.0 if x > 0 else -1.0)


class Pad(Protocol):
    """A gamepad device: its axes' travel and positions, and its events as they come."""

    name: str

    def travel(self) -> tuple[dict[int, Travel], dict[int, int]]:
        """Each absolute axis's travel, and where it is now, by code."""

    def read(self) -> list[tuple[int, int, int]]:
        """The events come since the last read, ``(type, code, value)`` (none: []); OSError: gone."""

    def close(self) -> None: ...


class EvdevPad:
    """The gamepad at ``path`` (``/dev/input/eventN``), else the first device that looks like
    one (a south button and a left stick); or ``device``, an evdev ``InputDevice`` opened already."""

    def __init__(self, path: str | None = None, device: Any = None) -> None:
        if device is None:
            ev = evdev()
            path = path or find_gamepad()
            try:
                device = ev.InputDevice(path)
            except OSError as e:
                raise BadRequest(f"cannot open the gamepad {path}: {e}", field="gamepad") from None
        self.device = device
        self.name = f"the gamepad {device.name!r} ({device.path})"

    def travel(self) -> tuple[dict[int, Travel], dict[int, int]]:
        caps = self.device.capabilities().get(EV_ABS, [])
        travel = {code: Travel(info.min, info.max, info.flat) for code, info in caps}
        return travel, {code: info.value for code, info in caps}

    def read(self) -> list[tuple[int, int, int]]:
        try:
            return [(e.type, e.code, e.value) for e in self.device.read()]
        except BlockingIOError:  # (nothing came)
            return []

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.device.close()


def find_gamepad() -> str:
    """The path of the first input device with a south button and a left stick, else
    :class:`BadRequest` saying what to check."""
    ev = evdev()
    codes = ev.ecodes
    for path in ev.list_devices():
        try:
            device = ev.InputDevice(path)
        except OSError:
            continue
        try:
            caps = device.capabilities(absinfo=False)
        finally:
            device.close()
        if codes.BTN_SOUTH in caps.get(EV_KEY, []) and codes.ABS_X in caps.get(EV_ABS, []):
            return str(path)
    raise BadRequest(
        "no gamepad among the input devices (/dev/input/event*): plug one in, check that this user may read "
        "them (the 'input' group), or name it: --gamepad /dev/input/eventN",
        field="gamepad",
    )


class Gamepad:
    """The gamepad ``open_pad()`` opens (again after it went), jogging with ``jog``."""

    def __init__(self, jog: Jog, open_pad: Callable[[], Pad], *, retry: float = RETRY) -> None:
        self.jog = jog
        self.retry = retry
        self.name = "the gamepad"
        self.active = False  # putting (from the first push; not after a stop until the next)
        self._rested = True  # the sticks were at rest since the stop (one still pushed then moves nothing)
        self._open_pad = open_pad
        self._pad: Pad | None = None
        self._map: PadMap | None = None
        self._why = ""
        self._retry_at = 0.0

    def start(self) -> None:
        """Open the pad the first time (else the error, as it is)."""
        self._attach(self._open_pad())

    def _attach(self, pad: Pad) -> None:
        travel, at = pad.travel()
        self._pad, self._map, self.name = pad, PadMap(travel, at), pad.name

    def poll(self) -> Step:
        now = time.monotonic()
        if self._pad is None:
            if now < self._retry_at:
                return Lost(self._why)
            try:
                self._attach(self._open_pad())
            except (BadRequest, OSError) as e:  # (not back yet)
                log.debug("the gamepad is not back: %s", e)
                self._retry_at = now + self.retry
                return Lost(self._why)
        assert self._pad is not None and self._map is not None
        try:
            events = self._pad.read()
        except OSError as e:
            self._why = f"{self.name} is gone ({e.strerror or e})"
            self._pad.close()
            self._pad = None
            self._retry_at = now + self.retry
            return Lost(self._why)
        stop = False
        for type_, code, value in events:
            command = self._map.feed(type_, code, value)
            if command == "stop":
                stop = True
            elif command == "faster":
                self.jog.faster()
            elif command == "slower":
                self.jog.slower()
            elif command in ("open", "close"):
                self.jog.grip(1.0 if command == "open" else 0.0)
                self.active = True
        axes = self._map.axes()
        if stop:
            self.active, self._rested = False, axes.still
            return Stop()
        self._rested = self._rested or axes.still
        if not axes.still and self._rested:
            self.active = True
        return self.jog.put(axes) if self.active else None

    def close(self) -> None:
        if self._pad is not None:
            self._pad.close()
            self._pad = None
