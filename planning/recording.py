"""A recording of an arm moved by hand (``armd record``) or driven through its tracking stream
(``armd record --teleop``), and the ways it is replayed (``armd replay``): checked, smoothed,
reduced to via points, split where the gripper moves; or its commands put again on the stream.

The file is JSON (docs/adapters.md, "Teach and replay")::

    {"format": "armd-recording", "version": 2, "robot": "so101",
     "joints": ["shoulder_pan", ...], "unit": "rad",
     "t": [0.0, 0.02, ...],                     # [s] from the start, increasing
     "q": [[0.01, -1.2, ...], ...],             # [rad] one joint vector a reading
     "gripper": [0.0, 0.0, ...],                # opening in [0, 1] a reading, or null
     "state": {"adapter": "sim-4f2a", "source": "commanded"},   # optional: who said where the arm was
     "commands": [{"t": 0.013, "put": {"session": "...", "seq": 0, "target": [...], ...}}, ...]}

Version 1 has no ``commands`` and no ``state``: ``armd record`` of an arm by hand writes it
still (any armd reads it), and it is read as it always was. Version 2 (``armd record
--teleop``) adds ``commands``: every put heard on ``<prefix>/<robot>/track`` while recording
(a list, empty if none was), ``t`` [s] on the readings' clock, never falling, and ``put`` the
JSON object as it was sent; and ``state``, optional: the adapter whose state the readings are
and its ``source`` (``measured`` or ``commanded``, as the adapter says). Its ``gripper`` is
the opening that adapter last said it commanded (its ``gripper`` events), the first one standing
for the readings before it; null if it commanded none.

A replay is the recording's path, not its timing: each part between gripper changes is one
jerk-limited ``move`` through its via points, timed by the service within every limit. A
stream replay (``armd replay --stream``) puts the commands again at their own pace, and the
service's tracker keeps every limit as it did the first time.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from armd.errors import BadRequest
from armd.robots import Robot

from .state import FloatArray

FORMAT = "armd-recording"
VERSION = 2  # written when a recording has commands; else version 1, which every armd reads
VERSIONS = (1, 2)  # read
LIMIT_SLACK = 0.02  # [rad] how far outside a limit a reading may be (a servo's noise at the end): brought inside
JUMP_STEP = 0.05  # [rad] a change between two readings this large ...
JUMP_SPEED = 15.0  # [rad/s] ... and this fast is a jump (no hand turns a joint so): a glitch, a lost calibration
SMOOTH = 0.05  # [s] the moving average's window (a count's noise smoothed out)
TOLERANCE = 0.01  # [rad] how far the via points' path may leave the smoothed recording, per joint
GRIPPER_STEP = 0.1  # a change of the gripper's opening this large is a gripper action ...
GRIPPER_SETTLE = 0.2  # [s] ... which ends when the opening stays within a fifth of that this long
MAX_VIA = 100  # via points of one move: the service's own limit (max_waypoints)
MAX_READINGS = 2_000_000  # readings of one recording (about 2 hours at 300 a second) ...
MAX_FILE_BYTES = 400_000_000  # ... and its file's size
MAX_COMMANDS = 2_000_000  # commands of one recording (about 5 hours at 100 a second)
STATE_KEYS = ("adapter", "source")  # what ``state`` may say, each a short string
MAX_NAME = 64  # characters of each


class Command(NamedTuple):
    """A put on the arm's tracking stream: ``t`` [s] on the recording's clock (the readings')
    and ``put``, the JSON object as it was sent."""

    t: float
    put: dict[str, Any]


@dataclass(frozen=True)
class Recording:
    """``position[k]`` [rad] of ``joints`` at ``times[k]`` [s]; ``gripper[k]`` its opening;
    ``commands``: the tracking stream's puts (None: an arm recorded by hand, version 1);
    ``state``: the adapter whose state the readings are, and its source."""

    robot: str
    joints: tuple[str, ...]
    times: FloatArray
    position: FloatArray
    gripper: FloatArray | None = None
    commands: tuple[Command, ...] | None = None
    state: Mapping[str, str] | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": FORMAT,
            "version": 1 if self.commands is None else VERSION,
            "robot": self.robot,
            "joints": list(self.joints),
            "unit": "rad",
            "t": [round(float(t), 6) for t in self.times],
            "q": [[round(float(x), 6) for x in row] for row in self.position],
            "gripper": None if self.gripper is None else [round(float(g), 4) for g in self.gripper],
        }
        if self.commands is not None:
            if self.state is not None:
                out["state"] = dict(self.state)
            out["commands"] = [{"t": round(float(c.t), 6), "put": c.put} for c in self.commands]
        return out

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_json(), allow_nan=False) + "\n")

    @classmethod
    def from_json(cls, data: object) -> Recording:
        """A recording from its JSON form, its shape checked (else :class:`BadRequest` naming the field)."""
        if not isinstance(data, dict):
            raise BadRequest("a recording is a JSON object", field="recording")
        if data.get("format") != FORMAT or type(data.get("version")) is not int or data["version"] not in VERSIONS:
            raise BadRequest(
                f"not an armd recording: format {data.get('format')!r} version {data.get('version')!r} "
                f"(expected {FORMAT!r} version {' or '.join(map(str, VERSIONS))})",
                field="format",
            )
        if data["version"] >= 2 and "commands" not in data:
            raise BadRequest(
                "not an armd recording of version 2: it has no commands (a list, empty if nothing was put)",
                field="format",
            )
        if data.get("unit", "rad") != "rad":
            raise BadRequest(f"unit must be 'rad', got {data.get('unit')!r}", field="unit")
        robot, joints = data.get("robot"), data.get("joints")
        if not isinstance(robot, str) or not isinstance(joints, list) or not all(isinstance(j, str) for j in joints):
            raise BadRequest("robot must be a name and joints a list of names", field="robot")
        t = _numbers(data.get("t"), "t", 1)
        q = _numbers(data.get("q"), "q", 2)
        g = None if data.get("gripper") is None else _numbers(data["gripper"], "gripper", 1)
        n = len(t)
        if not 2 <= n <= MAX_READINGS or q.shape != (n, len(joints)) or (g is not None and g.shape != (n,)):
            raise BadRequest(
                f"t must list 2 to {MAX_READINGS} readings, q one vector of {len(joints)} joints a reading and "
                f"gripper one number a reading: t {t.shape}, q {q.shape}"
                + ("" if g is None else f", gripper {g.shape}"),
                field="q",
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and (g is None or np.all(np.isfinite(g)))):
            raise BadRequest("t, q and gripper must be finite", field="q")
        if np.any(np.diff(t) <= 0.0):
            k = int(np.argmax(np.diff(t) <= 0.0))
            raise BadRequest(f"t must increase: reading {k + 1} at {t[k + 1]:g} s after {t[k]:g} s", field="t")
        if g is not None and (np.any(g < 0.0) or np.any(g > 1.0)):
            raise BadRequest("gripper openings must be in [0, 1]", field="gripper")
        if data["version"] == 1:
            return cls(robot, tuple(joints), t, q, g)
        return cls(robot, tuple(joints), t, q, g, _commands(data["commands"]), _state(data.get("state")))

    @classmethod
    def load(cls, path: Path) -> Recording:
        try:
            if path.stat().st_size > MAX_FILE_BYTES:
                raise BadRequest(
                    f"the recording {path} is larger than {MAX_FILE_BYTES // 1_000_000} MB", field="recording"
                )
            data = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise BadRequest(f"cannot read the recording {path}: {e}", field="recording") from None
        return cls.from_json(data)


def _numbers(value: object, field: str, depth: int) -> FloatArray:
    """``value`` as an array of ``depth`` nested lists of numbers (not strings, not booleans),
    else :class:`BadRequest` naming ``field``."""
    rows = value if depth == 2 else [value]
    if not isinstance(rows, list) or not all(isinstance(r, list) for r in rows):
        raise BadRequest(f"{field} must be a list{' of lists' if depth == 2 else ''} of numbers", field=field)
    if not all(type(x) in (int, float) for r in rows for x in r):  # (type: a bool is an int to isinstance)
        raise BadRequest(f"{field} must hold numbers only", field=field)
    if depth == 2 and len({len(r) for r in rows}) > 1:
        raise BadRequest(f"{field}'s readings must all have one length", field=field)
    out = np.array(rows, dtype=float)
    return out if depth == 2 else out.reshape(-1)


def _commands(value: object) -> tuple[Command, ...]:
    """A version 2 file's ``commands``: a list of ``{"t": [s], "put": {...}}``, ``t`` finite and
    never falling; else :class:`BadRequest` naming the command."""
    if not isinstance(value, list) or len(value) > MAX_COMMANDS:
        raise BadRequest(f"commands must be a list of at most {MAX_COMMANDS} puts", field="commands")
    out: list[Command] = []
    for k, c in enumerate(value):
        if not isinstance(c, dict) or set(c) != {"t", "put"}:
            raise BadRequest(f"commands[{k}] must be an object of t [s] and put (the put as sent)", field="commands")
        t, put = c["t"], c["put"]
        if type(t) not in (int, float) or not math.isfinite(t):
            raise BadRequest(f"commands[{k}].t must be a finite number of seconds, got {t!r}", field="commands")
        if not isinstance(put, dict):
            raise BadRequest(f"commands[{k}].put must be the put's JSON object, got {put!r:.40}", field="commands")
        if out and t < out[-1].t:
            raise BadRequest(
                f"commands must be in time order: commands[{k}] at {t:g} s after {out[-1].t:g} s", field="commands"
            )
        out.append(Command(float(t), put))
    return tuple(out)


def _state(value: object) -> dict[str, str] | None:
    """A version 2 file's ``state``: absent, or an object of ``adapter`` and ``source``, short strings."""
    if value is None:
        return None
    if (
        not isinstance(value, dict)
        or not set(value) <= set(STATE_KEYS)
        or not all(isinstance(v, str) and len(v) <= MAX_NAME for v in value.values())
    ):
        raise BadRequest(
            f"state must be an object of {' and '.join(STATE_KEYS)}, strings of at most {MAX_NAME} characters",
            field="state",
        )
    return dict(value)


def stream_start(rec: Recording) -> int:
    """The reading where a stream replay starts: the last one at or before the first command
    (the arm's pose when the stream began), else the first."""
    if not rec.commands:
        return 0
    return max(int(np.searchsorted(rec.times, rec.commands[0].t, side="right")) - 1, 0)


@dataclass(frozen=True)
class Part:
    """A stretch of a replay: a move through ``via`` to ``goal`` [rad], then the gripper to
    ``gripper`` (None: left as it is)."""

    via: list[FloatArray]
    goal: FloatArray
    gripper: float | None
    start_time: float  # [s] in the recording
    end_time: float


def check(rec: Recording, robot: Robot) -> FloatArray:
    """The recording's positions, once it is known to fit ``robot``: its arm and joints, every
    reading inside the limits (within ``LIMIT_SLACK``: brought inside), no jump; else
    :class:`BadRequest` saying which reading and joint."""
    if rec.robot != robot.name or list(rec.joints) != list(robot.joint_names):
        raise BadRequest(
            f"the recording is of {rec.robot} ({', '.join(rec.joints)}), not {robot.name} "
            f"({', '.join(robot.joint_names)})",
            field="robot",
        )
    t, q = rec.times, rec.position
    step = np.abs(np.diff(q, axis=0))
    fast = (step > JUMP_STEP) & (step / np.diff(t)[:, None] > JUMP_SPEED)
    if np.any(fast):
        k, j = (int(x) for x in np.argwhere(fast)[0])
        raise BadRequest(
            f"a jump in the recording: {robot.joint_names[j]} from {q[k, j]:.4f} to {q[k + 1, j]:.4f} rad between "
            f"{t[k]:.3f} s and {t[k + 1]:.3f} s ({step[k, j] / (t[k + 1] - t[k]):.0f} rad/s; a hand turns a joint "
            f"slower than {JUMP_SPEED:g}): a lost reading or calibration; record it again",
            field="q",
        )
    lim = robot.limits
    for k, row in enumerate(q):
        if not lim.contains(row, tol=LIMIT_SLACK):
            bad = lim.violations(row, tol=LIMIT_SLACK)
            raise BadRequest(f"the reading at {t[k]:.3f} s is outside the limits: {bad[0].message}", field="q")
    inside = np.clip(q, lim.lower, lim.upper)
    for k, row in enumerate(inside):  # (the coupled limits, and the actuators' ranges)
        if not lim.contains(row, tol=1e-9):
            raise BadRequest(f"the reading at {t[k]:.3f} s is outside the limits", field="q")
        robot.actuators.commands(row)  # (ActuatorRangeError: a BadRequest naming the actuator)
    return inside


def smooth(times: FloatArray, q: FloatArray, window: float = SMOOTH) -> FloatArray:
    """``q`` averaged over ``window`` [s] about each reading (the ends kept as they are)."""
    n = len(times)
    out = q.copy()
    lo = np.searchsorted(times, times - window / 2, side="left")
    hi = np.searchsorted(times, times + window / 2, side="right")
    csum = np.vstack([np.zeros(q.shape[1]), np.cumsum(q, axis=0)])
    for k in range(1, n - 1):
        a, b = lo[k], hi[k]
        out[k] = (csum[b] - csum[a]) / (b - a)
    return out


def simplify(q: FloatArray, tolerance: float = TOLERANCE) -> list[int]:
    """The indices of the fewest readings (the first and last among them) whose straight joint
    segments stay within ``tolerance`` [rad], per joint, of every reading: Douglas-Peucker, each
    reading measured against the point as far along its segment as the reading is along the
    recording's path between the segment's ends (so a motion that goes back over its own way,
    0 -> 1 -> 0 -> 1, keeps its turns: measured against the nearest point of the segment, it
    would be lost)."""
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])  # [rad] path length
    keep = {0, len(q) - 1}
    stack = [(0, len(q) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        span = along[b] - along[a]
        s = (along[a + 1 : b] - along[a]) / span if span > 0.0 else np.zeros(b - a - 1)
        err = np.max(np.abs(q[a + 1 : b] - (q[a] + s[:, None] * (q[b] - q[a]))), axis=1)
        k = int(np.argmax(err))
        if err[k] > tolerance:
            m = a + 1 + k
            keep.add(m)
            stack += [(a, m), (m, b)]
    return sorted(keep)


def gripper_actions(times: FloatArray, g: FloatArray) -> list[tuple[int, float]]:
    """Where the gripper opens or closes: ``(k, opening)``, the reading ``k`` where it starts to
    move (by ``GRIPPER_STEP`` from where it was held) and the opening it settles at (within
    ``GRIPPER_STEP / 5`` for ``GRIPPER_SETTLE``, or at the recording's end): a slow close by
    hand is one action, not one for every step."""
    out: list[tuple[int, float]] = []
    held = g[0]
    k = 1
    while k < len(g):
        if abs(g[k] - held) < GRIPPER_STEP:
            k += 1
            continue
        e = k
        while e < len(g) - 1:
            calm = np.flatnonzero((times >= times[e]) & (times <= times[e] + GRIPPER_SETTLE))
            if np.all(np.abs(g[calm] - g[e]) <= GRIPPER_STEP / 5) and times[-1] >= times[e] + GRIPPER_SETTLE:
                e = int(calm[-1])  # (where it came to rest)
                break
            e += 1
        out.append((k, float(g[e])))
        held = g[e]
        k = e + 1
    return out


def parts(rec: Recording, robot: Robot, *, tolerance: float = TOLERANCE, max_via: int = 50) -> list[Part]:
    """The replay of ``rec`` on ``robot``: checked (:func:`check`), smoothed, reduced to via points
    within ``tolerance`` [rad] of it (:func:`simplify`), split where the gripper opens or closes
    (:func:`gripper_actions`: the arm stops at its pose of that moment, then the gripper moves)
    and into moves of at most ``max_via`` via points."""
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise BadRequest(f"tolerance must be a positive number of radians, got {tolerance!r}", field="tolerance")
    if isinstance(max_via, bool) or not isinstance(max_via, int) or not 0 <= max_via <= MAX_VIA:
        raise BadRequest(f"max_via must be a whole number in [0, {MAX_VIA}], got {max_via!r}", field="max_via")
    q = check(rec, robot)
    q = np.clip(smooth(rec.times, q), robot.limits.lower, robot.limits.upper)
    g = rec.gripper
    actions = gripper_actions(rec.times, g) if g is not None else []
    cuts = [0, *(k for k, _ in actions)]  # reading indices where a part ends: each gripper action, and the last
    grips = [*(o for _, o in actions)]
    if cuts[-1] != len(q) - 1:
        cuts.append(len(q) - 1)
        grips.append(float(g[-1]) if g is not None else math.nan)
    # first, to where the recording starts (the arm may be anywhere), the gripper as it was
    out = [Part([], q[0], None if g is None else float(g[0]), float(rec.times[0]), float(rec.times[0]))]
    for (a, b), grip in zip(itertools.pairwise(cuts), grips, strict=True):
        idx = [a + i for i in simplify(q[a : b + 1], tolerance)]
        for s in range(0, len(idx) - 1, max_via + 1):
            chunk = idx[s : s + max_via + 2]
            last = chunk[-1] == idx[-1]
            out.append(
                Part(
                    [q[i] for i in chunk[1:-1]],
                    q[chunk[-1]],
                    grip if g is not None and last else None,
                    float(rec.times[chunk[0]]),
                    float(rec.times[chunk[-1]]),
                )
            )
    return out
