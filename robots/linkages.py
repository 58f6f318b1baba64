"""Nonlinear actuator linkages: a servo that moves a joint through a four-bar linkage.

An ideal parallelogram makes the servo's angle a linear function of the joints (the desk4
minor servo's ``q2 + q3``: a row of ``a = M q + b``); a real one, with a bent lever and links of
other lengths, does not. Seed 004 section 4 computes such a "bent arm" angle through a chain of
triangles; :class:`FourBar` is that computation, with its derivative and inverse.

The linkage lies in one plane. Angles are absolute, in the joints' sense, from the plane's
horizontal; lengths are in metres:

- ``O``: the servo's axis, the origin. The ``frame`` link ``O -> E`` (length ``frame``) turns
  with the ``input`` joint: ``E = frame (cos q_in, sin q_in)`` (the desk4 major arm, whose
  pivot the servo shares).
- ``E``: the ``driven`` joint's axis. The driven link's absolute angle is ``phi = q_in +
  q_dr``; its ``lever`` (length ``lever``) points back from ``E``, bent by ``bend`` from
  straight behind the link: ``C = E + lever (cos psi, sin psi)``, ``psi = phi + pi + bend``.
- ``H = horn (cos s, sin s)``: the end of the servo's horn; a ``rod`` joins ``H`` to ``C``.
- The actuator angle is the horn's angle from straight behind: ``a = s - pi`` (wrapped to
  (-pi, pi]). A parallelogram (``lever = horn``, ``rod = frame``, ``bend = 0``) gives
  ``a = phi``.

Forward (the seed's triangles): ``OC`` (the seed's red edge) follows from the triangle
``O E C`` (sides ``frame`` and ``lever`` about ``E``); the triangle ``O C H`` (sides ``|OC|``,
``horn``, ``rod``) gives the angle ``theta6`` at ``O`` between ``OC`` and ``OH`` by the law of
cosines; ``s = angle(OC) + assembly * theta6``. ``assembly`` (+1 or -1) is which side of ``OC``
the horn lies: the linkage's assembly mode.

Derivative: implicitly, from ``|H(s) - C(q)|^2 = rod^2``:
``ds/dq_k = ((H - C) . dC/dq_k) / ((H - C) . dH/ds)``.

Inverse (hardware read-back): given ``a`` and ``q_in``, ``C`` is where the circles about ``E``
(radius ``lever``) and ``H`` (radius ``rod``) meet; of the two, the one the forward assembly
reaches (found once, when the linkage is checked).

:func:`check` proves a linkage over the joints' range at load: it assembles everywhere with the
rod away from the horn's line (the transmission angle within 15..165 degrees), the actuator
angle is monotone in the driven joint (so the inverse is unique), and the inverse recovers
every joint vector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .types import FloatArray

TRANSMISSION_MIN = math.radians(15.0)  # [rad] the rod and the horn at least this far from a line
SLOPE_MIN = 0.1  # the actuator angle turns at least this much per radian of the driven joint
GRID = 121  # points per joint when a linkage is checked over its range (and its bounds found)


def wrap(x: FloatArray) -> FloatArray:
    """Angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


@dataclass(frozen=True)
class FourBar:
    """A servo driving joint ``driven`` through a four-bar whose frame link turns with joint
    ``input`` (indices into ``q``). See the module's text for the geometry."""

    input: int
    driven: int
    frame: float
    lever: float
    rod: float
    horn: float
    bend: float = 0.0
    assembly: int = 1
    # set when checked (:meth:`check`), over the joints' range: the driven joint's span [rad],
    # each joint's largest and smallest |da/dq|, and |d2a/dq2| (n, n) at its largest
    span: tuple[float, float] | None = None
    steepest: FloatArray = field(default_factory=lambda: np.zeros(0), compare=False, repr=False)
    gentlest: FloatArray = field(default_factory=lambda: np.zeros(0), compare=False, repr=False)
    curvature: FloatArray = field(default_factory=lambda: np.zeros((0, 0)), compare=False, repr=False)

    kind = "four_bar"

    # -- forward ------------------------------------------------------------------------------

    def _points(self, q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        q = np.asarray(q, dtype=float)
        q_in, q_dr = q[..., self.input], q[..., self.driven]
        ex, ey = self.frame * np.cos(q_in), self.frame * np.sin(q_in)
        psi = q_in + q_dr + np.pi + self.bend
        cx, cy = ex + self.lever * np.cos(psi), ey + self.lever * np.sin(psi)
        return ex, ey, cx, cy, psi

    def _horn(self, cx: FloatArray, cy: FloatArray) -> FloatArray:
        """The horn's absolute angle ``s`` for rod end ``C`` (NaN where the links cannot meet)."""
        d = np.hypot(cx, cy)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos6 = (d * d + self.horn**2 - self.rod**2) / (2.0 * d * self.horn)
            theta6 = np.arccos(np.where(np.abs(cos6) <= 1.0, cos6, np.nan))
        return np.arctan2(cy, cx) + self.assembly * theta6

    def angle(self, q: FloatArray) -> FloatArray:
        """The actuator angle [rad] of joint vector(s) ``q`` (..., n) -> (...); NaN where the
        linkage cannot be assembled."""
        _, _, cx, cy, _ = self._points(q)
        return wrap(self._horn(cx, cy) - np.pi)

    def gradient(self, q: FloatArray) -> FloatArray:
        """``da/dq`` (..., n): zero but for the input and driven joints."""
        q = np.asarray(q, dtype=float)
        ex, ey, cx, cy, psi = self._points(q)
        s = self._horn(cx, cy)
        hx, hy = self.horn * np.cos(s), self.horn * np.sin(s)
        rx, ry = hx - cx, hy - cy  # H - C
        with np.errstate(invalid="ignore", divide="ignore"):
            den = rx * (-hy) + ry * hx  # (H - C) . dH/ds
            lever = (rx * (-self.lever * np.sin(psi)) + ry * (self.lever * np.cos(psi))) / den
            frame = (rx * (-ey) + ry * ex) / den
        out = np.zeros(q.shape, dtype=float)
        out[..., self.driven] = lever
        out[..., self.input] = lever + frame
        return out

    def transmission(self, q: FloatArray) -> FloatArray:
        """The angle [rad] between the rod and the horn, 0..pi (0 or pi: a dead point)."""
        _, _, cx, cy, _ = self._points(q)
        s = self._horn(cx, cy)
        hx, hy = self.horn * np.cos(s), self.horn * np.sin(s)
        rx, ry = cx - hx, cy - hy
        cross = hx * ry - hy * rx
        dot = hx * rx + hy * ry
        return np.abs(np.arctan2(cross, dot))

    # -- inverse ------------------------------------------------------------------------------

    def joint(self, a: FloatArray, q: FloatArray, span: tuple[float, float] | None = None) -> FloatArray:
        """The driven joint [rad] that puts the actuator at angle(s) ``a`` with the input joint
        as in ``q`` (..., n); NaN where no joint value does.

        The rod and the lever meet at two points; each is kept if the forward map gives ``a``
        back (the linkage's assembly reaches it). Of those, the one inside the driven joint's
        ``span`` (its range: the linkage is monotone there, so at most one is), else the nearest
        to it; without a span, the nearest to ``q``'s driven entry (modulo 2 pi)."""
        q = np.array(q, dtype=float)
        a = np.asarray(a, dtype=float)
        q_in = q[..., self.input]
        ex, ey = self.frame * np.cos(q_in), self.frame * np.sin(q_in)
        s = a + np.pi
        hx, hy = self.horn * np.cos(s), self.horn * np.sin(s)
        dx, dy = hx - ex, hy - ey
        d = np.hypot(dx, dy)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_e = (self.lever**2 + d * d - self.rod**2) / (2.0 * self.lever * d)
            alpha = np.arccos(np.where(np.abs(cos_e) <= 1.0, cos_e, np.nan))
        span = span or self.span
        near = q[..., self.driven] if span is None else np.full(np.shape(a), (span[0] + span[1]) / 2.0)
        best = np.full(np.shape(a), np.nan)
        score = np.full(np.shape(a), np.inf)
        for tau in (1.0, -1.0):
            psi = np.arctan2(dy, dx) + tau * alpha
            cand = near + wrap(psi - np.pi - self.bend - q_in - near)
            q[..., self.driven] = cand
            reached = np.abs(wrap(self.angle(q) - a)) < 1e-7
            away = np.abs(cand - near) if span is None else np.maximum(span[0] - cand, cand - span[1]).clip(0.0)
            better = reached & (away < score)
            best = np.where(better, cand, best)
            score = np.where(better, away, score)
        return best

    # -- at load ------------------------------------------------------------------------------

    def check(self, region: FloatArray) -> Checked:
        """Prove the linkage over ``region`` (m, n): joint vectors filling the joints' range.
        Returns it with its span, slopes and curvature set, and the actuator angle's range
        there; raises :class:`ValueError` saying what fails, and where."""
        for name in ("frame", "lever", "rod", "horn"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive length [m], got {value!r}")
        if self.assembly not in (1, -1):
            raise ValueError(f"assembly must be 1 or -1, got {self.assembly!r}")
        a = self.angle(region)
        bad = ~np.isfinite(a)
        if np.any(bad):
            raise ValueError(f"cannot be assembled at {_where(region[np.argmax(bad)], self)}: the rod does not reach")
        mu = self.transmission(region)
        low = np.minimum(mu, np.pi - mu)
        if np.min(low) < TRANSMISSION_MIN:
            k = int(np.argmin(low))
            raise ValueError(
                f"the rod and the horn are {math.degrees(float(low[k])):.1f} degrees from a line at "
                f"{_where(region[k], self)} (at least {math.degrees(TRANSMISSION_MIN):.0f}: near a dead point the "
                "servo cannot drive the joint)"
            )
        slope = self.gradient(region)[:, self.driven]
        sign = np.sign(np.median(slope))
        if np.min(sign * slope) < SLOPE_MIN:
            k = int(np.argmin(sign * slope))
            raise ValueError(
                f"is not monotone in the driven joint over its range: da/dq = {float(slope[k]):.3g} at "
                f"{_where(region[k], self)} (every slope must keep one sign, at least {SLOPE_MIN} in size)"
            )
        span = (float(np.min(region[:, self.driven])), float(np.max(region[:, self.driven])))
        back = self.joint(a, region, span)
        miss = np.abs(back - region[:, self.driven])
        if not np.all(miss < 1e-9):
            k = int(np.argmax(np.where(np.isfinite(miss), miss, np.inf)))
            raise ValueError(f"its inverse does not recover the driven joint at {_where(region[k], self)}")
        centre = float(np.median(a))
        if not np.allclose(centre + wrap(a - centre), a) or np.ptp(a) >= np.pi:
            raise ValueError("the actuator angle (the horn from straight behind) crosses +-pi over the range")
        grad = self.gradient(region)
        n = region.shape[1]
        curvature = np.zeros((n, n))
        h = 1e-5
        for j in (self.input, self.driven):
            step = np.zeros(n)
            step[j] = h
            d2 = (self.gradient(region + step) - self.gradient(region - step)) / (2.0 * h)
            curvature[:, j] = np.max(np.abs(d2), axis=0)
        steepest, gentlest = np.max(np.abs(grad), axis=0), np.min(np.abs(grad), axis=0)
        checked = replace(self, span=span, steepest=steepest, gentlest=gentlest, curvature=curvature)
        return Checked(checked, (float(np.min(a)), float(np.max(a))))

    def describe(self) -> dict[str, object]:
        return {
            "type": self.kind,
            "frame": self.frame,
            "lever": self.lever,
            "rod": self.rod,
            "horn": self.horn,
            "bend": self.bend,
            "assembly": self.assembly,
        }


@dataclass(frozen=True)
class Checked:
    """A linkage proven over its range (its span, slopes and curvature set) and its actuator
    angle's range [rad] there."""

    linkage: FourBar
    angle_range: tuple[float, float]


def region(
    lower: FloatArray,
    upper: FloatArray,
    coupled: list[tuple[FloatArray, float, float]],
    pair: tuple[int, int],
    points: int = GRID,
) -> FloatArray:
    """Joint vectors (m, n) filling the joints ``pair``'s box ``lower..upper`` on a grid (the
    other joints at mid-range), kept where every ``(coefficients, low, high)`` on those two
    joints holds; the coupled limits' edges are sampled densely too (a function monotone in
    a joint has its extremes on the region's boundary)."""
    i, j = pair
    mid = (np.asarray(lower, dtype=float) + np.asarray(upper, dtype=float)) / 2.0
    own = [(c, lo, hi) for c, lo, hi in coupled if not np.any(np.delete(c, [i, j]))]
    ui, uj = np.linspace(lower[i], upper[i], points), np.linspace(lower[j], upper[j], points)
    gi, gj = np.meshgrid(ui, uj, indexing="ij")
    parts = [np.column_stack([gi.ravel(), gj.ravel()])]
    for c, lo, hi in own:  # the coupled limits' edges, where they cross the box
        if c[j] == 0:
            continue
        x = np.linspace(lower[i], upper[i], points * 8)
        for bound in (lo, hi):
            parts.append(np.column_stack([x, (bound - c[i] * x) / c[j]]))
    pts = np.vstack(parts)
    keep = (pts[:, 1] >= lower[j] - 1e-12) & (pts[:, 1] <= upper[j] + 1e-12)
    for c, lo, hi in own:
        v = c[i] * pts[:, 0] + c[j] * pts[:, 1]
        keep &= (v >= lo - 1e-9) & (v <= hi + 1e-9)
    out = np.tile(mid, (int(np.sum(keep)), 1))
    out[:, i], out[:, j] = pts[keep, 0], pts[keep, 1]
    return out


def _where(q: FloatArray, link: FourBar) -> str:
    return f"q[{link.input}] = {float(q[link.input]):.4f}, q[{link.driven}] = {float(q[link.driven]):.4f} rad"
