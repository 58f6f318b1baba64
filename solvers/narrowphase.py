"""The distance between two primitive shapes, compiled: closed forms where they exist, GJK elsewhere.

A shape is a kind and four numbers (:data:`SIZE`'s layout), placed by a (4, 4) homogeneous
matrix (rotation and position [m] in the base frame):

=========== ======================== ================================================
kind        size                     the shape, in its own frame
=========== ======================== ================================================
SPHERE      r                        ball of radius r about the origin
CAPSULE     r, h                     points within r of the segment z in [-h, h]
BOX         hx, hy, hz               ``|x| <= hx, |y| <= hy, |z| <= hz``
CYLINDER    r, h                     ``x^2 + y^2 <= r^2, |z| <= h``
HALFSPACE   nx, ny, nz, d            ``n . x <= d`` (n unit)
=========== ======================== ================================================

(coal's shapes, with coal's parameters: ``Sphere.radius``, ``Capsule.radius/halfLength``,
``Box.halfSide``, ``Cylinder.radius/halfLength``, ``Halfspace.n/d``.)

Every shape but the half-space is a convex *core* (a point, a segment, a box, a cylinder)
inflated by a radius (a sphere's and a capsule's; 0 for the others): the distance between two
shapes is their cores' distance less both radii. :func:`pair_distance` takes

- a half-space and anything: the lowest point of the other along the half-space's normal;
- two of sphere and capsule: the segments' closest points (Ericson, *Real-Time Collision
  Detection*, 5.1.9, parallel segments included);
- a sphere and a box or a cylinder: the point's distance to it in its own frame;
- everything else (box, cylinder, a capsule with either): GJK on the cores' support functions
  in the first shape's frame (van den Bergen's distance loop, Ericson's Voronoi-region
  projections on the simplex; the triangle's interior by its normal). It stops when the gap
  between the distance's upper bound ``|v|`` (a point of the Minkowski difference) and its
  lower bound ``v . w / |v|`` (a separating plane) is below :data:`GAP`; a polytope's loop ends
  exactly, a cylinder's converges.

The answer is the distance [m] where the shapes are apart (exact: to :data:`GAP` by GJK, to
rounding by the closed forms), and a number <= :data:`TOUCH` where they touch or overlap: a
sphere's or a capsule's overlap with a shape its core is apart from, else 0 less the radii. It
is not a penetration depth. Given ``stop``, a pair proved farther apart than ``stop`` returns a
lower bound above it as soon as it is known (a yes/no check asks no more).

coal, for comparison (tests/test_compiled_collision.py): its closed forms (half-spaces, sphere
pairs) are exact as these are; its GJK ends at a gap of 1e-6 (1 + d) (a box's or a cylinder's
distance off by up to ~1.5e-6 m), its collision check may call shapes within ~1e-5 m of
contact touching or clear (a 20 um overlap was missed), and nearer contact than ~1e-4 m its
distances are off by up to ~3e-7 m even with its tolerance at 1e-10.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import jit

IntArray = NDArray[np.int64]

SPHERE, CAPSULE, BOX, CYLINDER, HALFSPACE = 0, 1, 2, 3, 4  # a shape's kind
KINDS = ("sphere", "capsule", "box", "cylinder", "halfspace")
SIZE = 4  # numbers a shape's size takes (see the module's doc)

TOUCH = 1e-12  # [m]: a distance at or below this is a contact (coal's collision_distance_threshold)
GAP = 1e-10  # [m]: GJK stops when its upper and lower bounds on the distance are this close
ITERATIONS = 128  # GJK's iterations, at most (a box pair takes a handful, a cylinder pair about 10-30)
TINY = 1e-15  # [m]: a point of the Minkowski difference this near the origin is the origin
OVERLAP = 1e-9  # [m]: GJK ending this near the origin with no separating plane found: a contact

# (Every quotient is np.divide's, which never raises: a function that may raise Python's
# ZeroDivisionError keeps Numba from dropping its callers' reference counting of their arrays,
# atomic operations that cost more than a closed form.)


@jit
def inflation(kind: int, size: FloatArray, s: int) -> float:
    """The radius [m] shape ``s`` (a row of ``size``) is its core inflated by."""
    return size[s, 0] if kind in (SPHERE, CAPSULE) else 0.0


@jit
def core_support(
    kind: int, s0: float, s1: float, s2: float, dx: float, dy: float, dz: float
) -> tuple[float, float, float]:
    """The point of a core (``kind``, its size's first numbers ``s0, s1, s2``) farthest along
    (dx, dy, dz), both in its own frame."""
    if kind == BOX:
        return s0 if dx >= 0.0 else -s0, s1 if dy >= 0.0 else -s1, s2 if dz >= 0.0 else -s2
    if kind == CYLINDER:
        h = s1 if dz >= 0.0 else -s1
        rho = math.hypot(dx, dy)
        if rho == 0.0:  # (along the axis: the cap's centre is as far as any point of it)
            return 0.0, 0.0, h
        k = np.divide(s0, rho)
        return k * dx, k * dy, h
    if kind == CAPSULE:
        return 0.0, 0.0, s1 if dz >= 0.0 else -s1
    return 0.0, 0.0, 0.0


# -- closed forms ---------------------------------------------------------------------------------


@jit
def segments(
    px: float,
    py: float,
    pz: float,
    ux: float,
    uy: float,
    uz: float,
    qx: float,
    qy: float,
    qz: float,
    vx: float,
    vy: float,
    vz: float,
) -> float:
    """The distance [m] between segments p + s u and q + t v (s, t in [0, 1]; either may be a
    point): Ericson's ClosestPtSegmentSegment, the parallel case included."""
    rx, ry, rz = px - qx, py - qy, pz - qz
    a = ux * ux + uy * uy + uz * uz
    e = vx * vx + vy * vy + vz * vz
    f = vx * rx + vy * ry + vz * rz
    if a <= 0.0 and e <= 0.0:
        return math.sqrt(rx * rx + ry * ry + rz * rz)
    if a <= 0.0:
        s = 0.0
        t = min(max(np.divide(f, e), 0.0), 1.0)
    else:
        c = ux * rx + uy * ry + uz * rz
        if e <= 0.0:
            t = 0.0
            s = min(max(np.divide(-c, a), 0.0), 1.0)
        else:
            b = ux * vx + uy * vy + uz * vz
            denom = a * e - b * b
            s = min(max(np.divide(b * f - c * e, denom), 0.0), 1.0) if denom > 0.0 else 0.0
            t = np.divide(b * s + f, e)
            if t < 0.0:
                t = 0.0
                s = min(max(np.divide(-c, a), 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max(np.divide(b - c, a), 0.0), 1.0)
    dx = rx + s * ux - t * vx
    dy = ry + s * uy - t * vy
    dz = rz + s * uz - t * vz
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@jit
def point_core(kind: int, size: FloatArray, s: int, M: FloatArray, x: float, y: float, z: float) -> float:
    """The distance [m] from the point (x, y, z) to the core of box or cylinder ``s`` placed at
    ``M[s]`` (0 inside)."""
    dx, dy, dz = x - M[s, 0, 3], y - M[s, 1, 3], z - M[s, 2, 3]
    lx = M[s, 0, 0] * dx + M[s, 1, 0] * dy + M[s, 2, 0] * dz
    ly = M[s, 0, 1] * dx + M[s, 1, 1] * dy + M[s, 2, 1] * dz
    lz = M[s, 0, 2] * dx + M[s, 1, 2] * dy + M[s, 2, 2] * dz
    if kind == BOX:
        ex = max(abs(lx) - size[s, 0], 0.0)
        ey = max(abs(ly) - size[s, 1], 0.0)
        ez = max(abs(lz) - size[s, 2], 0.0)
        return math.sqrt(ex * ex + ey * ey + ez * ez)
    er = max(math.hypot(lx, ly) - size[s, 0], 0.0)
    ez = max(abs(lz) - size[s, 1], 0.0)
    return math.hypot(er, ez)


@jit
def above_halfspace(kind: int, size: FloatArray, s: int, h: int, M: FloatArray) -> float:
    """The signed distance [m] of shape ``s`` from half-space ``h`` (both placed by ``M``): its
    lowest point's height above the boundary along the normal, less its radius."""
    nlx, nly, nlz, d = size[h, 0], size[h, 1], size[h, 2], size[h, 3]
    nx = M[h, 0, 0] * nlx + M[h, 0, 1] * nly + M[h, 0, 2] * nlz
    ny = M[h, 1, 0] * nlx + M[h, 1, 1] * nly + M[h, 1, 2] * nlz
    nz = M[h, 2, 0] * nlx + M[h, 2, 1] * nly + M[h, 2, 2] * nlz
    d += nx * M[h, 0, 3] + ny * M[h, 1, 3] + nz * M[h, 2, 3]
    # the lowest point of the core: its support along -n, in its own frame
    dx = -(M[s, 0, 0] * nx + M[s, 1, 0] * ny + M[s, 2, 0] * nz)
    dy = -(M[s, 0, 1] * nx + M[s, 1, 1] * ny + M[s, 2, 1] * nz)
    dz = -(M[s, 0, 2] * nx + M[s, 1, 2] * ny + M[s, 2, 2] * nz)
    sx, sy, sz = core_support(kind, size[s, 0], size[s, 1], size[s, 2], dx, dy, dz)
    low = -(dx * sx + dy * sy + dz * sz) + nx * M[s, 0, 3] + ny * M[s, 1, 3] + nz * M[s, 2, 3]
    return low - d - inflation(kind, size, s)


# -- GJK ------------------------------------------------------------------------------------------


@jit
def _segment(
    ax: float, ay: float, az: float, bx: float, by: float, bz: float
) -> tuple[float, float, float, float, int]:
    """The point of segment ab nearest the origin, its squared norm, and which ends it needs
    (bits: 1 a, 2 b)."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    t = -(ax * ux + ay * uy + az * uz)
    uu = ux * ux + uy * uy + uz * uz
    if t <= 0.0 or uu <= 0.0:
        return ax, ay, az, ax * ax + ay * ay + az * az, 1
    if t >= uu:
        return bx, by, bz, bx * bx + by * by + bz * bz, 2
    t = np.divide(t, uu)
    x, y, z = ax + t * ux, ay + t * uy, az + t * uz
    return x, y, z, x * x + y * y + z * z, 3


@jit
def _triangle(
    ax: float, ay: float, az: float, bx: float, by: float, bz: float, cx: float, cy: float, cz: float
) -> tuple[float, float, float, float, int]:
    """The point of triangle abc nearest the origin, its squared norm, and which vertices it
    needs (bits: 1 a, 2 b, 4 c): Ericson's Voronoi regions (5.1.5), the interior by the plane's
    normal (accurate on a thin triangle)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    d1 = -(abx * ax + aby * ay + abz * az)
    d2 = -(acx * ax + acy * ay + acz * az)
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, ax * ax + ay * ay + az * az, 1
    d3 = -(abx * bx + aby * by + abz * bz)
    d4 = -(acx * bx + acy * by + acz * bz)
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz, bx * bx + by * by + bz * bz, 2
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        return _segment(ax, ay, az, bx, by, bz)  # (its bits 1 a, 2 b are the triangle's)
    d5 = -(abx * cx + aby * cy + abz * cz)
    d6 = -(acx * cx + acy * cy + acz * cz)
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz, cx * cx + cy * cy + cz * cz, 4
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        x, y, z, n2, m = _segment(ax, ay, az, cx, cy, cz)
        return x, y, z, n2, (m & 1) | (4 if m & 2 else 0)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        x, y, z, n2, m = _segment(bx, by, bz, cx, cy, cz)
        return x, y, z, n2, (2 if m & 1 else 0) | (4 if m & 2 else 0)
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    nn = nx * nx + ny * ny + nz * nz
    if nn <= 0.0:  # (a degenerate triangle: its nearest edge)
        x, y, z, n2, m = _segment(ax, ay, az, bx, by, bz)
        ex, ey, ez, e2, em = _segment(ax, ay, az, cx, cy, cz)
        if e2 < n2:
            x, y, z, n2, m = ex, ey, ez, e2, (em & 1) | (4 if em & 2 else 0)
        ex, ey, ez, e2, em = _segment(bx, by, bz, cx, cy, cz)
        if e2 < n2:
            x, y, z, n2, m = ex, ey, ez, e2, (2 if em & 1 else 0) | (4 if em & 2 else 0)
        return x, y, z, n2, m
    t = np.divide(nx * ax + ny * ay + nz * az, nn)
    x, y, z = nx * t, ny * t, nz * t
    return x, y, z, x * x + y * y + z * z, 7


@jit
def _face(
    px: float,
    py: float,
    pz: float,
    qx: float,
    qy: float,
    qz: float,
    rx: float,
    ry: float,
    rz: float,
    ox: float,
    oy: float,
    oz: float,
) -> bool:
    """Whether the origin is outside the tetrahedron's face pqr (on the other side of its plane
    than the fourth vertex o)."""
    ex, ey, ez = qx - px, qy - py, qz - pz
    fx, fy, fz = rx - px, ry - py, rz - pz
    nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
    return -(nx * px + ny * py + nz * pz) * (nx * (ox - px) + ny * (oy - py) + nz * (oz - pz)) < 0.0


@jit
def _tetrahedron(
    ax: float,
    ay: float,
    az: float,
    bx: float,
    by: float,
    bz: float,
    cx: float,
    cy: float,
    cz: float,
    dx: float,
    dy: float,
    dz: float,
) -> tuple[float, float, float, float, int]:
    """The point of tetrahedron abcd nearest the origin, its squared norm, and which vertices it
    needs (bits: 1 a, 2 b, 4 c, 8 d; 15 with the origin inside): the nearest of the faces the
    origin is outside of (Ericson 5.1.6); of every face where the tetrahedron is flat."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = cx - ax, cy - ay, cz - az
    wx, wy, wz = dx - ax, dy - ay, dz - az
    det = ux * (vy * wz - vz * wy) + uy * (vz * wx - vx * wz) + uz * (vx * wy - vy * wx)
    scale = (
        math.sqrt(ux * ux + uy * uy + uz * uz)
        * math.sqrt(vx * vx + vy * vy + vz * vz)
        * math.sqrt(wx * wx + wy * wy + wz * wz)
    )
    flat = abs(det) <= 1e-12 * scale  # (the sides' signs mean nothing: every face is a candidate)
    best, x, y, z, mask = math.inf, 0.0, 0.0, 0.0, 15
    if flat or _face(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
        fx, fy, fz, f2, m = _triangle(ax, ay, az, bx, by, bz, cx, cy, cz)
        if f2 < best:
            best, x, y, z, mask = f2, fx, fy, fz, m  # (bits a, b, c)
    if flat or _face(ax, ay, az, cx, cy, cz, dx, dy, dz, bx, by, bz):
        fx, fy, fz, f2, m = _triangle(ax, ay, az, cx, cy, cz, dx, dy, dz)
        if f2 < best:
            best, x, y, z, mask = f2, fx, fy, fz, (m & 1) | (4 if m & 2 else 0) | (8 if m & 4 else 0)
    if flat or _face(ax, ay, az, dx, dy, dz, bx, by, bz, cx, cy, cz):
        fx, fy, fz, f2, m = _triangle(ax, ay, az, dx, dy, dz, bx, by, bz)
        if f2 < best:
            best, x, y, z, mask = f2, fx, fy, fz, (m & 1) | (8 if m & 2 else 0) | (2 if m & 4 else 0)
    if flat or _face(bx, by, bz, dx, dy, dz, cx, cy, cz, ax, ay, az):
        fx, fy, fz, f2, m = _triangle(bx, by, bz, dx, dy, dz, cx, cy, cz)
        if f2 < best:
            best, x, y, z, mask = f2, fx, fy, fz, (2 if m & 1 else 0) | (8 if m & 2 else 0) | (4 if m & 4 else 0)
    if best == math.inf:
        return 0.0, 0.0, 0.0, 0.0, 15
    return x, y, z, best, mask


@jit
def gjk(
    ka: int, a0: float, a1: float, a2: float, kb: int, b0: float, b1: float, b2: float, work: FloatArray, stop: float
) -> float:
    """The distance [m] between two cores (kinds ``ka``, ``kb``, sizes' first numbers ``a0..a2``,
    ``b0..b2``), b placed in a's frame by ``work[4:7]`` (3, 4); or, once they are proved farther
    apart than ``stop``, a lower bound above it. ``work[:4, :3]``: scratch (the simplex)."""
    W = work
    r00, r01, r02, tx = work[4, 0], work[4, 1], work[4, 2], work[4, 3]
    r10, r11, r12, ty = work[5, 0], work[5, 1], work[5, 2], work[5, 3]
    r20, r21, r22, tz = work[6, 0], work[6, 1], work[6, 2], work[6, 3]
    # v: a point of the Minkowski difference a - b (the centres' difference to start)
    vx, vy, vz = -tx, -ty, -tz
    vv = vx * vx + vy * vy + vz * vz
    lower = 0.0
    n = 0
    for it in range(ITERATIONS):
        vn = math.sqrt(vv)
        if vn <= TINY:
            return 0.0
        # w: the Minkowski difference's support along -v: a's along -v less b's along v
        sax, say, saz = core_support(ka, a0, a1, a2, -vx, -vy, -vz)
        sbx, sby, sbz = core_support(
            kb,
            b0,
            b1,
            b2,
            r00 * vx + r10 * vy + r20 * vz,  # (v in b's frame)
            r01 * vx + r11 * vy + r21 * vz,
            r02 * vx + r12 * vy + r22 * vz,
        )
        wx = sax - (r00 * sbx + r01 * sby + r02 * sbz + tx)
        wy = say - (r10 * sbx + r11 * sby + r12 * sbz + ty)
        wz = saz - (r20 * sbx + r21 * sby + r22 * sbz + tz)
        plane = np.divide(vx * wx + vy * wy + vz * wz, vn)  # every point of a - b is at least this far along v
        lower = max(lower, plane)
        if lower > stop:
            return lower
        if vn - lower <= GAP:
            return _settled(vn, lower)
        for r in range(n):  # w is in the simplex already: nothing left to gain (rounding)
            if W[r, 0] == wx and W[r, 1] == wy and W[r, 2] == wz:
                return _settled(vn, lower)
        W[n, 0], W[n, 1], W[n, 2] = wx, wy, wz
        n += 1
        # the simplex's point nearest the origin, and the vertices it needs
        if n == 1:
            px, py, pz, pp, mask = wx, wy, wz, wx * wx + wy * wy + wz * wz, 1
        elif n == 2:
            px, py, pz, pp, mask = _segment(W[0, 0], W[0, 1], W[0, 2], W[1, 0], W[1, 1], W[1, 2])
        elif n == 3:
            px, py, pz, pp, mask = _triangle(
                W[0, 0], W[0, 1], W[0, 2], W[1, 0], W[1, 1], W[1, 2], W[2, 0], W[2, 1], W[2, 2]
            )
        else:
            px, py, pz, pp, mask = _tetrahedron(
                W[0, 0],
                W[0, 1],
                W[0, 2],
                W[1, 0],
                W[1, 1],
                W[1, 2],
                W[2, 0],
                W[2, 1],
                W[2, 2],
                W[3, 0],
                W[3, 1],
                W[3, 2],
            )
            if mask == 15:  # the origin is inside: the cores overlap
                return 0.0
        kept = 0
        for r in range(n):  # the vertices needed, in order, to the simplex's first rows
            if (r == 0 and mask & 1) or (r == 1 and mask & 2) or (r == 2 and mask & 4) or (r == 3 and mask & 8):
                W[kept, 0], W[kept, 1], W[kept, 2] = W[r, 0], W[r, 1], W[r, 2]
                kept += 1
        n = kept
        if it > 0 and pp >= vv:  # no progress (rounding): the best point found stands
            return _settled(vn, lower)
        vx, vy, vz, vv = px, py, pz, pp
    return _settled(math.sqrt(vv), lower)


@jit
def _settled(upper: float, lower: float) -> float:
    """GJK's answer from its bounds on the distance: ``upper`` (a point of the Minkowski
    difference), unless no separating plane was found (``lower`` still 0) and that point is
    within :data:`OVERLAP` of the origin: overlapping cores whose simplex came to the origin
    only to rounding (a box deep in a box ended at 3e-12 m, above TOUCH): 0, in contact."""
    return 0.0 if lower <= 0.0 and upper <= OVERLAP else upper


# -- a pair ---------------------------------------------------------------------------------------


@jit
def pair_distance(
    kind: IntArray, size: FloatArray, M: FloatArray, a: int, b: int, stop: float, work: FloatArray
) -> float:
    """The distance [m] between shapes ``a`` and ``b`` (rows of ``kind``, ``size`` and their
    placements ``M`` (S, 4, 4)) when they are apart, <= :data:`TOUCH` when they touch or overlap
    (see the module's doc); once proved farther apart than ``stop`` [m], a lower bound above it.
    ``work`` (7, 4): scratch."""
    ka, kb = kind[a], kind[b]
    if ka > kb:
        a, b, ka, kb = b, a, kb, ka
    if kb == HALFSPACE:
        if ka == HALFSPACE:
            return math.inf  # (two half-spaces: not a pair armd checks)
        return above_halfspace(ka, size, a, b, M)
    ra, rb = inflation(ka, size, a), inflation(kb, size, b)
    if kb <= CAPSULE:  # spheres and capsules: their segments (a sphere's: a point)
        ha, hb = (size[a, 1] if ka == CAPSULE else 0.0), (size[b, 1] if kb == CAPSULE else 0.0)
        core = segments(
            M[a, 0, 3] - ha * M[a, 0, 2],
            M[a, 1, 3] - ha * M[a, 1, 2],
            M[a, 2, 3] - ha * M[a, 2, 2],
            2.0 * ha * M[a, 0, 2],
            2.0 * ha * M[a, 1, 2],
            2.0 * ha * M[a, 2, 2],
            M[b, 0, 3] - hb * M[b, 0, 2],
            M[b, 1, 3] - hb * M[b, 1, 2],
            M[b, 2, 3] - hb * M[b, 2, 2],
            2.0 * hb * M[b, 0, 2],
            2.0 * hb * M[b, 1, 2],
            2.0 * hb * M[b, 2, 2],
        )
        return core - ra - rb
    if ka == SPHERE:  # a point and a box or a cylinder
        return point_core(kb, size, b, M, M[a, 0, 3], M[a, 1, 3], M[a, 2, 3]) - ra
    # b's placement in a's frame, (a's rotation)^T [b's rotation | b's position - a's], into work[4:7]
    tx, ty, tz = M[b, 0, 3] - M[a, 0, 3], M[b, 1, 3] - M[a, 1, 3], M[b, 2, 3] - M[a, 2, 3]
    for r in range(3):
        for c in range(3):
            work[4 + r, c] = M[a, 0, r] * M[b, 0, c] + M[a, 1, r] * M[b, 1, c] + M[a, 2, r] * M[b, 2, c]
        work[4 + r, 3] = M[a, 0, r] * tx + M[a, 1, r] * ty + M[a, 2, r] * tz
    core = gjk(ka, size[a, 0], size[a, 1], size[a, 2], kb, size[b, 0], size[b, 1], size[b, 2], work, stop + ra + rb)
    return core - ra - rb
