"""Compiled (numba) kernels of the triangulation-angle engine (:mod:`camplace.solver.engines.angle.search`).

Rows are laid out in 64-row words as in :mod:`camplace.solver._support.bitkernels`; every word is a
*block* of nearby points. A **cone** summarises where a camera (or a cluster of cameras) lies as
seen from any point of a block: the directions point -> camera all lie within ``alpha`` radians
of a unit ``axis``. Cones are computed in float64 and stored in 8 bytes (int16 axis, half-angle
in steps of pi / 2048 rounded up, widened by the axis rounding), so stored cones are never too
narrow; the tests against the minimum angle read precomputed cosine tables
(:func:`angle_tables`).

For two cones at angle ``g`` between their axes, the angle at any point of the block between a
ray to a camera of the first and a ray to a camera of the second lies in
``[g - a1 - a2, g + a1 + a2]`` (triangle inequality on the sphere), so a pair of clusters is
*never* valid on a block (upper end < min angle), *always* valid (lower end >= min angle) or
*mixed*. Only mixed blocks of single-camera pairs need the per-point angle, computed exactly as
:func:`camplace.solver.problem.objectives.mode_value` does.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from camplace.solver._support.bitkernels import _ctz, _missed_weight, all_leaves, group_tuple, shortfall, shortfall2_grouped, shortfall_fixed, split_tuple, split_tuple_by

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}
_PJIT = dict(_JIT, parallel=True)

ALPHA_STEPS = 2048  # cone half-angles are stored in steps of pi / ALPHA_STEPS, rounded up
_STEP = math.pi / ALPHA_STEPS
_Q = 32767.0  # unit axes are stored as int16 multiples of 1 / _Q
_AXIS_ERR = 3e-5  # radians: the stored axis is within this of the true one (0.5 / _Q per component)
_ALPHA_PAD = 1e-6  # radians added to every computed half-angle (rounding)
_DOT_EPS = 1e-4  # margin on cosine comparisons (int16 axes): a doubtful block is "mixed"


@numba.njit(**_JIT)
def _store(ax, ay, az, alpha, out):  # pragma: no cover - compiled
    """Quantise a cone (float64 unit axis, half-angle) into ``out`` (4,) int16, never narrower."""
    if alpha >= math.pi:
        out[0] = 0
        out[1] = 0
        out[2] = 0
        out[3] = ALPHA_STEPS
        return
    out[0] = np.int16(round(ax * _Q))
    out[1] = np.int16(round(ay * _Q))
    out[2] = np.int16(round(az * _Q))
    out[3] = np.int16(min(ALPHA_STEPS, int(math.ceil((alpha + _AXIS_ERR + _ALPHA_PAD) / _STEP))))


@numba.njit(**_JIT)
def _merge(sc, a, b, v):  # pragma: no cover - compiled
    """Smallest cone around cones ``a`` and ``b`` of ``sc`` ((N, 4) float64 rows: axis, half-angle),
    written to row ``v``."""
    a1 = sc[a, 3]
    a2 = sc[b, 3]
    if a1 >= math.pi or a2 >= math.pi:
        sc[v, 3] = 4.0
        return
    x1, y1, z1 = sc[a, 0], sc[a, 1], sc[a, 2]
    x2, y2, z2 = sc[b, 0], sc[b, 1], sc[b, 2]
    dot = max(-1.0, min(1.0, x1 * x2 + y1 * y2 + z1 * z2))
    g = math.acos(dot)
    if g + a2 <= a1:
        sc[v, 0], sc[v, 1], sc[v, 2], sc[v, 3] = x1, y1, z1, a1 + _ALPHA_PAD
        return
    if g + a1 <= a2:
        sc[v, 0], sc[v, 1], sc[v, 2], sc[v, 3] = x2, y2, z2, a2 + _ALPHA_PAD
        return
    alpha = 0.5 * (g + a1 + a2)
    if alpha >= math.pi - 1e-6 or g > math.pi - 1e-4:
        sc[v, 3] = 4.0
        return
    t = alpha - a1  # the new axis turns from axis a towards axis b by t (0 < t < g)
    px, py, pz = x2 - dot * x1, y2 - dot * y1, z2 - dot * z1
    pn = math.sqrt(px * px + py * py + pz * pz)
    if pn < 1e-12:
        sc[v, 0], sc[v, 1], sc[v, 2], sc[v, 3] = x1, y1, z1, max(a1, a2) + g + _ALPHA_PAD
        return
    ct, st = math.cos(t), math.sin(t)
    ax, ay, az = ct * x1 + st * px / pn, ct * y1 + st * py / pn, ct * z1 + st * pz / pn
    an = math.sqrt(ax * ax + ay * ay + az * az)
    sc[v, 0], sc[v, 1], sc[v, 2], sc[v, 3] = ax / an, ay / an, az / an, alpha + _ALPHA_PAD


@numba.njit(**_PJIT)
def node_cones(campos, slot, left, right, centers, radius, out):  # pragma: no cover - compiled
    """Cones of every node of a bisection tree on every block.

    Per block (in parallel): each camera's cone from the block's bounding sphere (half-angle
    ``asin(radius / distance)``), then, bottom-up, the smallest cone around the two children of
    each inner node (float64), stored quantised.

    Parameters
    ----------
    campos : (n, 3) float64
        Camera positions.
    slot : (n,) int64
        Tree node of each camera (a leaf).
    left, right : (N,) int64
        The tree (children numbered after their parents; -1 at leaves). All -1: just the cameras.
    centers : (W, 3) float64, radius : (W,) float64
        Bounding spheres of the blocks' points (radius < 0: empty block).
    out : (N, W, 4) int16
        Receives ``(ax, ay, az)`` (units of 1 / 32767) and the half-angle in steps of
        ``pi / ALPHA_STEPS`` (``ALPHA_STEPS``: no information).
    """
    n = campos.shape[0]
    n_nodes = left.shape[0]
    n_words = centers.shape[0]
    for wd in prange(n_words):
        sc = np.zeros((n_nodes, 4))
        rho = radius[wd]
        for c in range(n):
            v = slot[c]
            if rho < 0:  # no point: any cone is right
                sc[v, 2] = 1.0
                continue
            dx = campos[c, 0] - centers[wd, 0]
            dy = campos[c, 1] - centers[wd, 1]
            dz = campos[c, 2] - centers[wd, 2]
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if d <= rho * (1.0 + 1e-9) + 1e-12:
                sc[v, 3] = 4.0
                continue
            sc[v, 0], sc[v, 1], sc[v, 2] = dx / d, dy / d, dz / d
            sc[v, 3] = math.asin(min(1.0, rho / d)) + _ALPHA_PAD
        for v in range(n_nodes - 1, -1, -1):
            if left[v] >= 0:
                _merge(sc, left[v], right[v], v)
        for v in range(n_nodes):
            _store(sc[v, 0], sc[v, 1], sc[v, 2], sc[v, 3], out[v, wd])


def angle_tables(theta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lookup tables over the summed half-angle steps ``s`` of two cones (``beta = s pi / ALPHA_STEPS``).

    Returns
    -------
    possible : (2 ALPHA_STEPS + 1,) float64
        ``cos(theta - beta)``: a pair may make the angle where the axes' cosine is at most this
        (2.0 when ``beta >= theta``: always may).
    always : (2 ALPHA_STEPS + 1,) float64
        ``cos(theta + beta)``: every pair makes the angle where the axes' cosine is at most this
        (-2.0 when ``theta + beta > pi``: never known).
    self_ok : (ALPHA_STEPS + 1,) bool
        Two cameras of one cone may make the angle (``2 alpha >= theta``).
    """
    beta = np.arange(2 * ALPHA_STEPS + 1) * _STEP
    possible = np.where(beta >= theta, 2.0, np.cos(np.maximum(theta - beta, 0.0)))
    always = np.where(theta + beta > math.pi, -2.0, np.cos(np.minimum(theta + beta, math.pi)))
    self_ok = 2.0 * np.arange(ALPHA_STEPS + 1) * _STEP >= theta - 1e-9
    return possible, always, self_ok


@numba.njit(inline="always", **_JIT)
def _dot(c1, i1, c2, i2, wd):  # pragma: no cover - compiled
    return (float(c1[i1, wd, 0]) * float(c2[i2, wd, 0]) + float(c1[i1, wd, 1]) * float(c2[i2, wd, 1])
            + float(c1[i1, wd, 2]) * float(c2[i2, wd, 2])) * (1.0 / (_Q * _Q))


@numba.njit(inline="always", **_JIT)
def _pair_state(c1, i1, c2, i2, wd, possible, always):  # pragma: no cover - compiled
    """0: no pair of the two clusters makes the angle anywhere in block ``wd``; 2: every pair does
    everywhere; 1: mixed (or unknown)."""
    s = np.int64(c1[i1, wd, 3]) + np.int64(c2[i2, wd, 3])
    lim = possible[s]
    if lim > 1.5:
        return 1 if always[s] < -1.5 else (2 if _dot(c1, i1, c2, i2, wd) <= always[s] - _DOT_EPS else 1)
    dot = _dot(c1, i1, c2, i2, wd)
    if dot > lim + _DOT_EPS:
        return 0
    return 2 if dot <= always[s] - _DOT_EPS else 1


@numba.njit(inline="always", **_JIT)
def _possible(c1, i1, c2, i2, wd, possible):  # pragma: no cover - compiled
    """False when no pair of the two clusters makes the angle anywhere in block ``wd``."""
    lim = possible[np.int64(c1[i1, wd, 3]) + np.int64(c2[i2, wd, 3])]
    return lim > 1.5 or _dot(c1, i1, c2, i2, wd) <= lim + _DOT_EPS


@numba.njit(**_JIT)
def angle_ok(p, a, b, theta_deg, cos_t):  # pragma: no cover - compiled
    """The rays p -> a and p -> b make an angle >= theta_deg (the formula of ``mode_value``;
    ``cos_t`` is ``cos(theta)``, which decides every case but near-ties without an arccos)."""
    ax, ay, az = a[0] - p[0], a[1] - p[1], a[2] - p[2]
    bx, by, bz = b[0] - p[0], b[1] - p[1], b[2] - p[2]
    na = max(math.sqrt(ax * ax + ay * ay + az * az), 1e-300)
    nb = max(math.sqrt(bx * bx + by * by + bz * bz), 1e-300)
    d = (ax / na) * (bx / nb) + (ay / na) * (by / nb) + (az / na) * (bz / nb)
    if d < cos_t - 1e-9:
        return True
    if d > cos_t + 1e-9:
        return False
    d = max(-1.0, min(1.0, d))
    return np.degrees(np.arccos(d)) >= theta_deg


@numba.njit(**_JIT)
def _exact_bits(x, wd, pa, pb, pts, theta_deg, cos_t):  # pragma: no cover - compiled
    """The rows of word ``x`` (block ``wd``) where cameras at pa and pb make the angle."""
    out = np.uint64(0)
    while x:
        t = _ctz(x)
        if angle_ok(pts[(wd << 6) + t], pa, pb, theta_deg, cos_t):
            out |= np.uint64(1) << t
        x &= x - np.uint64(1)
    return out


@numba.njit(inline="always", **_JIT)
def _pair_bits(x, exact, c1, i1, c2, i2, wd, possible, always, pa, pb, pts, theta_deg, cos_t):  # pragma: no cover - compiled
    """The bits of ``x`` (rows of word ``wd``) that a camera of cluster ``i1`` and one of ``i2``
    can see under the angle: all of ``x`` when the clusters' cones allow it everywhere, none when
    nowhere, else (``exact``, one camera each at ``pa`` / ``pb``) the rows checked one by one;
    without ``exact`` every row the cones do not rule out."""
    if not exact:
        return x if _possible(c1, i1, c2, i2, wd, possible) else np.uint64(0)
    s = _pair_state(c1, i1, c2, i2, wd, possible, always)
    if s == 0:
        return np.uint64(0)
    if s == 2:
        return x
    return _exact_bits(x, wd, pa, pb, pts, theta_deg, cos_t)


_BALL_STEPS = 48  # centre steps of node_balls (Badoiu-Clarkson) after the bounding box's centre


@numba.njit(**_PJIT)
def node_balls(campos, lo, hi):  # pragma: no cover - compiled
    """(N, 4) float64: a ball (centre, radius) around the camera positions of every tree node
    (columns ``lo[v]:hi[v]`` of ``campos``, tree order); radius 0 for a single camera, else the
    largest distance from the centre, padded so that it is never too small.

    The centre starts at the bounding box's centre and takes :data:`_BALL_STEPS` steps towards
    the farthest camera (``c += (far - c) / (i + 2)``, Badoiu-Clarkson: towards the smallest
    enclosing ball); the centre of the smallest radius met is kept. Any centre gives a valid ball;
    on comet-flyby at 32,000 positions the radii are 7-9 % below the box centre's (nodes of 6 to
    384 columns), and the refinement's arcs with them. In parallel over the nodes (each on its
    own: the same balls at every thread count)."""
    n_nodes = lo.shape[0]
    out = np.zeros((n_nodes, 4))
    for v in prange(n_nodes):
        a, b = lo[v], hi[v]
        if b - a == 1:
            for d in range(3):
                out[v, d] = campos[a, d]
            continue
        c = np.empty(3)
        for d in range(3):
            mn = campos[a, d]
            mx = campos[a, d]
            for j in range(a + 1, b):
                mn = min(mn, campos[j, d])
                mx = max(mx, campos[j, d])
            c[d] = 0.5 * (mn + mx)
        best = np.inf
        for i in range(_BALL_STEPS + 1):
            r2 = -1.0
            far = a
            for j in range(a, b):
                dx, dy, dz = campos[j, 0] - c[0], campos[j, 1] - c[1], campos[j, 2] - c[2]
                q = dx * dx + dy * dy + dz * dz
                if q > r2:
                    r2 = q
                    far = j
            if r2 < best:
                best = r2
                out[v, 0], out[v, 1], out[v, 2] = c[0], c[1], c[2]
            for d in range(3):
                c[d] += (campos[far, d] - c[d]) / (i + 2)
        # the radius from the kept centre, computed again (the same sums) and padded
        r2 = 0.0
        for j in range(a, b):
            dx, dy, dz = campos[j, 0] - out[v, 0], campos[j, 1] - out[v, 1], campos[j, 2] - out[v, 2]
            r2 = max(r2, dx * dx + dy * dy + dz * dz)
        out[v, 3] = math.sqrt(r2) * (1.0 + 1e-9) + 1e-12
    return out


@numba.njit(inline="always", **_JIT)
def _ball_sin(bx, by, bz, rho, centers, radius, wd):  # pragma: no cover - compiled
    """Sine of the arc within which, from any point of block ``wd`` (bounding sphere
    ``centers[wd]``, ``radius[wd]``), the direction to any camera of a ball (centre, radius
    ``rho``) lies around the direction to the ball's centre: ``rho / d`` with ``d`` the least
    distance from the block's sphere to the centre (2.0 when they meet: any direction; 0 for a
    single camera). The arc itself, ``asin`` of it, is never computed (:func:`ball_angle_table`
    holds the margins). Used by the repeated-node test of :func:`angle_shortfall` (the pairs'
    test, :func:`_ball_bits`, takes the arcs row by row)."""
    if rho <= 0.0:
        return 0.0
    dx, dy, dz = bx - centers[wd, 0], by - centers[wd, 1], bz - centers[wd, 2]
    d = math.sqrt(dx * dx + dy * dy + dz * dz) - max(radius[wd], 0.0)
    if d <= rho * (1.0 + 1e-9):
        return 2.0
    return rho / d


@numba.njit(**_JIT)
def ball_angle_table(theta):  # pragma: no cover - compiled
    """(3,) float64 for :func:`_ball_bits` and the repeated-node test of :func:`angle_shortfall`:
    ``cos`` and ``sin`` of ``theta - 3 _ALPHA_PAD`` (the angle less a rounding margin for each of
    two arcs and for their difference) and ``sin((theta - 3 _ALPHA_PAD) / 2)`` (a node's cameras
    make no pair among themselves where the sine of its arc is below it), ``theta`` in radians."""
    t = max(theta - 3.0 * _ALPHA_PAD, 0.0)
    return np.array([math.cos(t), math.sin(t), math.sin(0.5 * t)])


@numba.njit(**_JIT)
def _ball_bits(x, wd, ax, ay, az, ra, bx, by, bz, rb, pts, trig, centers, radius):  # pragma: no cover - compiled
    """The bits of ``x`` (rows of word ``wd``) where a camera in the ball around ``(ax, ay, az)``
    of radius ``ra`` and one in the ball around ``(bx, by, bz)`` of radius ``rb`` (metres; 0: one
    camera) may make the angle ``theta`` (``trig``: :func:`ball_angle_table`).

    From a row's point ``p``, a camera of the first ball lies within ``A = asin(ra / |u|)`` of the
    direction ``u`` to its centre (``|u|``: the distance from that point, not from the block's
    sphere), one of the second within ``B = asin(rb / |v|)`` of ``v``, so a pair makes at most the
    angle between ``u`` and ``v`` plus ``A + B`` (triangle inequality on the sphere of directions):
    a row is kept where that reaches ``theta`` less the table's margin, or where ``p`` is inside a
    ball. Per row, with the tangent lengths ``P = sqrt(|u|^2 - ra^2)``, ``Q = sqrt(|v|^2 - rb^2)``:
    ``cos(A + B) |u| |v| = P Q - ra rb`` and ``sin(A + B) |u| |v| = ra Q + rb P``, so
    ``sin(theta - A - B) |u| |v|`` (at most 0: ``A + B >= theta``, kept) and
    ``cos(theta - A - B) |u| |v|`` (kept where ``u . v`` is at most it) need two square roots a row
    and no arc sine; all 64 rows of the word at once (vectorised), masked by ``x``. (Until issue
    30's eighth round the arcs were taken from the block's sphere, one per block: a block 55 m
    across seen from 30 m had arcs of any width and kept every row.)

    Every row is kept without a look at the rows where the least arcs over the block's sphere,
    ``asin(r / (d + rk))`` (``d``: the centre's distance from the block's centre, ``rk`` its
    radius), already sum to ``theta`` (coarse nodes close by), and where, from the block's centre,
    the two centres are ``theta`` apart plus both their parallaxes over the block's sphere (the
    common case where the angle hardly binds): both give what the row test would."""
    cth, sth = trig[0], trig[1]
    cx, cy, cz, rk = centers[wd, 0], centers[wd, 1], centers[wd, 2], max(radius[wd], 0.0)
    ux, uy, uz = ax - cx, ay - cy, az - cz
    vx, vy, vz = bx - cx, by - cy, bz - cz
    nu = math.sqrt(ux * ux + uy * uy + uz * uz)
    nv = math.sqrt(vx * vx + vy * vy + vz * vz)
    # from every row's point the arcs are at least asin(r / (d + rk)): when those reach the angle
    # (or a ball holds the whole block), the row test keeps every row
    sa, sb = ra / (nu + rk), rb / (nv + rk)
    if sa >= 1.0 or sb >= 1.0:
        return x
    if math.sqrt(1.0 - sa * sa) * math.sqrt(1.0 - sb * sb) - sa * sb <= cth - 1e-12:
        return x
    if nu > rk * (1.0 + 1e-9) and nv > rk * (1.0 + 1e-9):
        su, sv = min(1.0, rk / nu), min(1.0, rk / nv)  # sines of the parallaxes U, V
        cu, cv = math.sqrt(max(0.0, 1.0 - su * su)), math.sqrt(max(0.0, 1.0 - sv * sv))
        cp, sp = cu * cv - su * sv, su * cv + cu * sv  # U + V in [0, pi]
        sfar = sth * cp + cth * sp  # sin(theta + U + V): positive when theta + U + V < pi
        if sfar > 1e-9 and ux * vx + uy * vy + uz * vz <= (cth * cp - sth * sp - _ALPHA_PAD) * nu * nv:
            return x  # from every point of the block the centres are at least theta apart
    ra2, rb2, rab = ra * ra * (1.0 + 1e-9), rb * rb * (1.0 + 1e-9), ra * rb
    out = np.uint64(0)
    base = wd << 6
    for t in range(64):  # every row of the word, no branch (vectorised); the rows of x kept below
        r = base + t
        ux, uy, uz = ax - pts[r, 0], ay - pts[r, 1], az - pts[r, 2]
        vx, vy, vz = bx - pts[r, 0], by - pts[r, 1], bz - pts[r, 2]
        nu2 = ux * ux + uy * uy + uz * uz
        nv2 = vx * vx + vy * vy + vz * vz
        uv = ux * vx + uy * vy + uz * vz
        tp = math.sqrt(max(nu2 - ra2, 0.0))
        tq = math.sqrt(max(nv2 - rb2, 0.0))
        cab = tp * tq - rab  # cos(A + B) |u| |v|
        sab = ra * tq + rb * tp  # sin(A + B) |u| |v|
        tol = 1e-12 * (nu2 + nv2)
        keep = ((sth * cab - cth * sab <= tol) | (uv <= cth * cab + sth * sab + tol)
                | (nu2 <= ra2) | (nv2 <= rb2))
        out |= np.uint64(keep) << np.uint64(t)
    return out & x


@numba.njit(**_JIT)
def _self_bits(x, wd, ax, ay, az, ra, pts, trig):  # pragma: no cover - compiled
    """The bits of ``x`` (rows of word ``wd``) where two cameras in one ball (centre ``(ax, ay,
    az)``, radius ``ra``) may make the angle ``theta``: from a row's point at distance ``d`` from
    the centre they are at most ``2 asin(ra / d)`` apart, so a row is kept where ``ra / d`` is at
    least ``sin(theta / 2)`` less the table's margin (``trig[2]``; compared in squares), or where
    the point is inside the ball. All 64 rows at once, masked by ``x``."""
    s2 = trig[2] * trig[2] * (1.0 - 1e-9)
    ra2 = ra * ra
    out = np.uint64(0)
    base = wd << 6
    for t in range(64):
        r = base + t
        ux, uy, uz = ax - pts[r, 0], ay - pts[r, 1], az - pts[r, 2]
        keep = ra2 >= s2 * (ux * ux + uy * uy + uz * uz)
        out |= np.uint64(keep) << np.uint64(t)
    return out & x


@numba.njit(**_JIT)
def angle_shortfall(levels, cones, nodes, k, views, lo, campos, fbits, fcones, fpos, fpair, w, planes, last_mask,
                    need, acc, gnode, gcnt, pw, exact, pts, possible, always, self_ok, theta_deg, cos_t, balls,
                    centers, radius):  # pragma: no cover - compiled
    """Weight of the rows a node tuple cannot make count (stops once it reaches ``need``).

    A row counts when at least ``views`` chosen cameras (the tuple's and the fixed ones) observe it
    and two of them make the angle there. Per block: a repeated node (``c >= 2`` columns) gives
    pairs among its rows seen twice (``levels[1]``) if its cone is at least ``theta`` wide; two
    nodes (or a node and a fixed camera) give pairs on the rows both observe unless their cones say
    "never"; fixed pairs are precomputed exactly (``fpair``). With ``exact`` (a tuple of single
    columns) mixed blocks are decided row by row, so the result is the exact shortfall.

    Parameters
    ----------
    levels : (L, N, W) uint64
        Level bitsets of the tree nodes.
    cones : (N, W, 4) int16
        Node cones per block (:func:`node_cones`).
    nodes : (k,) int64
        The tuple (non-decreasing).
    lo : (N,) int64
        First column position of each node (a leaf's column).
    campos : (n, 3) float64
        Camera positions in tree order.
    fbits : (r, W) uint64, fcones : (r, W, 4) int16, fpos : (r, 3) float64
        Fixed cameras.
    fpair : (W,) uint64
        Rows where two fixed cameras make the angle.
    w, planes, last_mask, pw
        Row weights and layout as in :func:`camplace.solver._support.bitkernels.shortfall`.
    acc : (views + 1,) uint64, gnode, gcnt : (k,) int64
        Scratch.
    pts : (64 W, 3) float64
        Point of each row position.
    possible, always, self_ok
        :func:`angle_tables` of the minimum angle.
    theta_deg, cos_t : float
        The minimum angle in degrees, and its cosine.
    balls : (N, 4) float64
        A ball around each node's camera positions (:func:`node_balls`; (0, 4): not used). Where
        two nodes' cones are mixed on a block, the rows are tested one by one against the balls
        (:func:`_ball_bits`): a node of cameras standing close together (the aims of one
        position, neighbouring positions) is a narrow cone from every single point, however wide
        the block. A repeated node whose ball is narrower than the angle from all of a block
        gives no pair there.
    centers : (W, 3) float64, radius : (W,) float64
        The blocks' bounding spheres (radius < 0: empty block).
    """
    n_words = levels.shape[2]
    n_levels = levels.shape[0]
    n_planes = planes.shape[0]
    r = fbits.shape[0]
    ng = group_tuple(nodes, k, gnode, gcnt)
    use_balls = balls.shape[0] > 0
    trig = ball_angle_table(math.radians(theta_deg))
    total = 0.0
    for wd in range(n_words):
        if pw <= wd < 2 * pw:
            continue  # second rows of pairs: counted with their first rows
        hit = np.uint64(0)
        for ww in range(wd, wd + pw + 1, pw) if wd < pw else range(wd, wd + 1):
            ph = fpair[ww]
            for a in range(ng):
                va = gnode[a]
                xa = levels[0, va, ww]
                if xa == 0:
                    continue
                if gcnt[a] >= 2 and n_levels >= 2:
                    x = levels[1, va, ww] & ~ph
                    if x and self_ok[cones[va, ww, 3]]:
                        if use_balls and _ball_sin(balls[va, 0], balls[va, 1], balls[va, 2], balls[va, 3],
                                                   centers, radius, ww) < trig[2] - 1e-12:
                            x = np.uint64(0)  # every two cameras of the node closer than the angle here
                        elif use_balls:  # row by row, from each row's distance
                            x = _self_bits(x, ww, balls[va, 0], balls[va, 1], balls[va, 2], balls[va, 3], pts, trig)
                        ph |= x
                for b in range(a + 1, ng):
                    vb = gnode[b]
                    x = xa & levels[0, vb, ww] & ~ph
                    if x:
                        if exact or not use_balls:
                            ph |= _pair_bits(x, exact, cones, va, cones, vb, ww, possible, always, campos[lo[va]],
                                             campos[lo[vb]], pts, theta_deg, cos_t)
                            continue
                        st = _pair_state(cones, va, cones, vb, ww, possible, always)
                        if st == 2:
                            ph |= x
                        elif st == 1:
                            ph |= _ball_bits(x, ww, balls[va, 0], balls[va, 1], balls[va, 2], balls[va, 3],
                                             balls[vb, 0], balls[vb, 1], balls[vb, 2], balls[vb, 3], pts, trig,
                                             centers, radius)
                for f in range(r):
                    x = xa & fbits[f, ww] & ~ph
                    if x:
                        if exact or not use_balls:
                            ph |= _pair_bits(x, exact, cones, va, fcones, f, ww, possible, always, campos[lo[va]],
                                             fpos[f], pts, theta_deg, cos_t)
                            continue
                        st = _pair_state(cones, va, fcones, f, ww, possible, always)
                        if st == 2:
                            ph |= x
                        elif st == 1:
                            ph |= _ball_bits(x, ww, balls[va, 0], balls[va, 1], balls[va, 2], balls[va, 3],
                                             fpos[f, 0], fpos[f, 1], fpos[f, 2], 0.0, pts, trig, centers, radius)
            if views > 2 and ph:
                acc[0] = ~np.uint64(0)
                for t in range(1, views + 1):
                    acc[t] = 0
                for a in range(ng):
                    v = gnode[a]
                    cm = min(gcnt[a], n_levels)
                    for t in range(views, 0, -1):
                        add = np.uint64(0)
                        for j in range(1, min(cm, t) + 1):
                            add |= acc[t - j] & levels[j - 1, v, ww]
                        acc[t] |= add
                for f in range(r):
                    y = fbits[f, ww]
                    for t in range(views, 0, -1):
                        acc[t] |= acc[t - 1] & y
                ph &= acc[views]
            hit |= ph
        total += _missed_weight(hit, wd, n_words, last_mask, planes, n_planes, w)
        if total >= need:
            return total
    return total


@numba.njit(inline="always", **_JIT)
def _far(dirs, par, a, b, theta):  # pragma: no cover - compiled
    """Cameras ``a`` and ``b`` (rows of ``dirs`` / ``par``) make at least ``theta`` at every point
    of the sphere: their directions from its centre are ``theta`` plus both parallaxes apart."""
    lim = theta + par[a] + par[b] + 1e-6
    if lim >= math.pi:
        return False
    d = dirs[a, 0] * dirs[b, 0] + dirs[a, 1] * dirs[b, 1] + dirs[a, 2] * dirs[b, 2]
    return d <= math.cos(lim) - 1e-12


@numba.njit(**_JIT)
def angle_free(nodes, k, lo, hi, dirs, par, n_fixed, theta):  # pragma: no cover - compiled
    """True when the angle removes no credit from the node tuple ``nodes``: every two of its
    nodes (and every node and the fixed camera; at most one) hold two cameras that make the angle
    at every point (:func:`_far` on the nodes' first and last cameras, rows ``lo`` / ``hi - 1`` of
    ``dirs`` and ``par``, fixed camera at row ``n``), a repeated node too.

    Then no two nodes' cones can be "never" on a block (the cones hold those cameras), so
    :func:`angle_shortfall` equals :func:`count_shortfall`; for a tuple of single columns every
    observed pair makes the angle, so the count value is the exact value.

    Parameters
    ----------
    dirs : (n + r, 3) float64
        Unit directions from the centre of a sphere around every point to the cameras (tree order),
        then to the fixed cameras.
    par : (n + r,) float64
        Their parallax over that sphere, ``asin(radius / distance)`` (``pi / 2`` inside it), radians.
    n_fixed : int
        Fixed cameras (more than one: False, their own pairs need the angle).
    theta : float
        The minimum angle, radians.
    """
    if n_fixed > 1:
        return False
    n = dirs.shape[0] - 1  # the fixed camera's row
    for a in range(k):
        va = nodes[a]
        if a > 0 and nodes[a - 1] == va:
            if not _far(dirs, par, lo[va], hi[va] - 1, theta):
                return False
            continue
        for b in range(a + 1, k):
            vb = nodes[b]
            if vb == va:
                continue
            if not (_far(dirs, par, lo[va], lo[vb], theta) or _far(dirs, par, lo[va], hi[vb] - 1, theta)
                    or _far(dirs, par, hi[va] - 1, lo[vb], theta) or _far(dirs, par, hi[va] - 1, hi[vb] - 1, theta)):
                return False
        if n_fixed == 1 and not (_far(dirs, par, lo[va], n, theta) or _far(dirs, par, hi[va] - 1, n, theta)):
            return False
    return True


@numba.njit(**_JIT)
def count_shortfall(levels, nodes, k, views, fbits, w, planes, last_mask, need, acc, gnode, gcnt,
                    pw):  # pragma: no cover - compiled
    """Weight of the rows that fewer than ``views`` cameras of the node tuple and the fixed cameras
    can observe, angles ignored (stops once it reaches ``need``).

    The angle only removes credit, so this is at most :func:`angle_shortfall` of the same tuple:
    a cheap first test (the bit-parallel counter of :func:`camplace.solver._support.bitkernels.shortfall`,
    a few word operations per block) that prunes most tuples before any cone is read.
    Arguments are those of :func:`angle_shortfall` (``gnode``, ``gcnt``: (k,) int64 scratch).
    """
    r = fbits.shape[0]
    if r == 0 and views == 2:
        return shortfall2_grouped(levels, nodes, k, w, planes, last_mask, need, pw, gnode, gcnt)
    if r == 0:
        return shortfall(levels, nodes, k, views, w, planes, last_mask, need, acc, pw)
    return shortfall_fixed(levels, nodes, k, views, fbits, w, planes, last_mask, need, acc, pw)


@numba.njit(inline="always", **_JIT)
def _level(nodes, k, lo, hi):  # pragma: no cover - compiled
    """floor(log2) of the largest node's column count of a tuple."""
    big = 1
    for j in range(k):
        big = max(big, hi[nodes[j]] - lo[nodes[j]])
    lvl = 0
    while (1 << (lvl + 1)) <= big:
        lvl += 1
    return lvl


@numba.njit(**_PJIT)
def expand(front, front_bound, lo, hi, left, right, levels, cones, views, campos, fbits, fcones, fpos, fpair, w, planes, mask, total,
           best, margin, colmax, fixed_colsum, pw, pts, possible, always, self_ok, theta_deg, cos_t, dirs, par, refine,
           sample, rest, balls, centers, radius, split_score):  # pragma: no cover - compiled
    """Refine (if it is due) and split every tuple of ``front`` (F, k + 1) once and bound the children.

    A tuple's last entry says whether its bound already holds the angle (1) or is the count
    bound only (0). The cone refinement (:func:`angle_shortfall`) is lazy: it runs when a tuple is
    taken from the open set to be split (so the many tuples that never reach the top of the
    best-first order never pay for it), where ``refine[level]`` is set for the level
    ``floor(log2(largest node's columns))`` or on one tuple in ``sample``; a tuple it prunes is
    not split, one whose refined bound fell below ``rest`` (the best bound still open) comes back
    unsplit as its own only child (flag 1), and otherwise its children are capped by the refined
    bound.

    A child's bound is ``min(its parent's bound, (sum of its nodes' heaviest column weights + the
    fixed cameras' weights) / views, total - shortfall)`` (a parent's bound holds for every set of
    its children). The shortfall is the count's (:func:`count_shortfall`, angles ignored; it
    prunes most children), exact for a child :func:`angle_free` says the angle cannot remove
    credit from (flag 1); a tuple of single columns is decided exactly at once (its value is the
    set's exact value); other children keep the count bound (flag 0). Every choice gives a valid
    bound.

    Parameters
    ----------
    dirs, par
        See :func:`angle_free`.
    refine : (64,) bool
        Levels where tuples of clusters get the cone refinement.
    sample : int
        One tuple in ``sample`` gets it anyway (so the caller can judge the levels).
    rest : float
        The largest bound left in the open set (-inf if none).
    balls, centers, radius
        See :func:`angle_shortfall` (the refinement tests rows against the nodes' balls).
    split_score : (N,) float64
        A tuple of a level where the refinement is on splits its node of two or more columns with
        the largest score (:func:`~camplace.solver._support.bitkernels.split_tuple_by`; the
        engine's: the ball's radius, :func:`camplace.solver.engines.angle.search.split_score`),
        one of another level its largest node (:func:`~camplace.solver._support.bitkernels.split_tuple`).

    Returns
    -------
    children : (F, k + 1, k + 1) int64
        Nodes and the flag.
    value : (F, k + 1) float64
        -inf: not made, or cannot beat ``best + margin``.
    leaf : (F, k + 1) bool
    made, exact, pruned_by_count, angle_free, pruned_after_refinement, requeued : int
        Children bounded, tuples of single columns among them, children the count bound pruned,
        children found angle-free, tuples pruned by the refinement (before their split, or a
        tuple of single columns), and tuples that came back unsplit.
    refined : (F,) int8
        ``level + 1`` for a tuple the refinement did not prune, ``-(level + 1)`` for one it did,
        0 where it did not run.
    cut : (F,) float64
        For a refined tuple, the share of its bound's margin over ``best + margin`` the
        refinement removed: 1 when it pruned the tuple.
    """
    f_count, k1 = front.shape
    k = k1 - 1
    children = np.zeros((f_count, k + 1, k + 1), dtype=np.int64)
    value = np.full((f_count, k + 1), -np.inf)
    leaf = np.zeros((f_count, k + 1), dtype=np.bool_)
    made = np.zeros(f_count, dtype=np.int64)
    exact = np.zeros(f_count, dtype=np.int64)
    filtered = np.zeros(f_count, dtype=np.int64)
    free = np.zeros(f_count, dtype=np.int64)
    by_angle = np.zeros(f_count, dtype=np.int64)
    refined = np.zeros(f_count, dtype=np.int8)
    cut = np.zeros(f_count)
    requeued = np.zeros(f_count, dtype=np.int64)
    theta = math.radians(theta_deg)
    beat = best + margin
    for f in prange(f_count):
        acc = np.zeros(views + 1, dtype=np.uint64)
        gnode = np.zeros(k, dtype=np.int64)
        gcnt = np.zeros(k, dtype=np.int64)
        tup = front[f, :k]
        bound = front_bound[f]
        if front[f, k] == 0:
            lvl = _level(tup, k, lo, hi)
            if refine[lvl] or f % sample == 0:
                sf = angle_shortfall(levels, cones, tup, k, views, lo, campos, fbits, fcones, fpos, fpair, w, planes,
                                     mask, total - beat, acc, gnode, gcnt, pw, False, pts, possible, always, self_ok,
                                     theta_deg, cos_t, balls, centers, radius)
                cut[f] = min(1.0, max(0.0, bound - (total - sf)) / max(bound - beat, 1e-300))
                bound = min(bound, total - sf)
                if bound <= beat:
                    refined[f] = -(lvl + 1)
                    by_angle[f] += 1
                    continue
                refined[f] = lvl + 1
                if bound < rest:  # no longer among the best: back to the open set, refined
                    children[f, 0, :k] = tup
                    children[f, 0, k] = 1
                    value[f, 0] = bound
                    requeued[f] = 1
                    continue
        kids = children[f, :, :k]
        if refine[_level(tup, k, lo, hi)]:  # the angle binds here: the widest ball first
            n_kids = split_tuple_by(tup, split_score, lo, hi, left, right, kids)
        else:  # the count bound decides: the largest node first
            n_kids = split_tuple(tup, lo, hi, left, right, kids)
        made[f] = n_kids
        for q in range(n_kids):
            child = kids[q]
            wcap = fixed_colsum
            for j in range(k):
                wcap += colmax[child[j]]
            wcap = min(wcap / views, bound)
            if wcap <= beat:
                continue
            sf = count_shortfall(levels, child, k, views, fbits, w, planes, mask, total - beat, acc, gnode, gcnt, pw)
            if total - sf <= beat:
                filtered[f] += 1
                continue  # cannot win even without the angle
            is_leaf = all_leaves(child, lo, hi)
            exact[f] += is_leaf
            if angle_free(child, k, lo, hi, dirs, par, fbits.shape[0], theta):
                free[f] += 1  # sf (complete: the sum did not stop early) is the angle shortfall too
                children[f, q, k] = 1
            elif is_leaf:
                sf = angle_shortfall(levels, cones, child, k, views, lo, campos, fbits, fcones, fpos, fpair, w, planes,
                                     mask, total - beat, acc, gnode, gcnt, pw, True, pts, possible, always, self_ok,
                                     theta_deg, cos_t, balls, centers, radius)
                children[f, q, k] = 1
            b = min(wcap, total - sf)
            if b <= beat:
                by_angle[f] += 1
                continue
            value[f, q] = b
            leaf[f, q] = is_leaf
    return children, value, leaf, made.sum(), exact.sum(), filtered.sum(), free.sum(), by_angle.sum(), requeued.sum(), refined, cut


@numba.njit(**_JIT)
def selection_index(sel, n):  # pragma: no cover - compiled
    """(n,) int64: each column's position in ``sel``, -1 for a column not in it."""
    where = np.full(n, -1, dtype=np.int64)
    for t in range(sel.shape[0]):
        where[sel[t]] = t
    return where


@numba.njit(**_JIT)
def row_status_block(lo, hi, indptr, indices, data, where, n_sel, pos, pts, views, theta_deg, count, ok):  # pragma: no cover
    """:func:`row_status` of rows ``lo:hi``, written into ``count`` and ``ok`` (``where``:
    :func:`selection_index` of the cameras, ``n_sel`` of them)."""
    cos_t = math.cos(math.radians(theta_deg))
    obs = np.empty(n_sel, dtype=np.int64)
    for r in range(lo, hi):
        c = 0
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0 and where[indices[p]] >= 0:
                obs[c] = indices[p]
                c += 1
        count[r] = c
        if c < views or c < 2:
            continue
        found = False
        for a in range(c):
            for b in range(a + 1, c):
                if angle_ok(pts[r], pos[obs[a]], pos[obs[b]], theta_deg, cos_t):
                    found = True
                    break
            if found:
                break
        ok[r] = found


@numba.njit(**_JIT)
def row_status(indptr, indices, data, sel, pos, pts, views, theta_deg):  # pragma: no cover - compiled
    """Per row: how many cameras of ``sel`` observe it, and whether it counts (>= views of them and
    two making the angle). (On the pool: :func:`row_status_block`.)

    Returns
    -------
    count : (m,) int64
    ok : (m,) bool
    """
    m = indptr.shape[0] - 1
    count = np.zeros(m, dtype=np.int64)
    ok = np.zeros(m, dtype=np.bool_)
    row_status_block(0, m, indptr, indices, data, selection_index(sel, pos.shape[0]), sel.shape[0], pos, pts, views,
                     theta_deg, count, ok)
    return count, ok


@numba.njit(**_PJIT)
def gains(indptr, indices, data, w, sel, pos, pts, views, theta_deg, count, ok, n_chunks):  # pragma: no cover - compiled
    """(n,) float64: weight each column would add to the camera set ``sel`` (whose per-row state is
    ``count``, ``ok`` from :func:`row_status`). A heuristic: angles are compared by their cosine,
    without the near-tie care of :func:`angle_ok`."""
    cos_t = math.cos(math.radians(theta_deg))
    m = indptr.shape[0] - 1
    n = pos.shape[0]
    where = np.full(n, -1, dtype=np.int64)
    for t in range(sel.shape[0]):
        where[sel[t]] = t
    out = np.zeros((n_chunks, n))
    step = (m + n_chunks - 1) // n_chunks
    for ch in prange(n_chunks):
        obs = np.empty(sel.shape[0], dtype=np.int64)
        u = np.empty((sel.shape[0], 3))
        for r in range(ch * step, min(m, (ch + 1) * step)):
            if ok[r] or w[r] <= 0 or count[r] == 0 or count[r] + 1 < views:
                continue
            c = 0
            for p in range(indptr[r], indptr[r + 1]):
                if data[p] > 0 and where[indices[p]] >= 0:
                    obs[c] = indices[p]
                    c += 1
            px, py, pz = pts[r, 0], pts[r, 1], pts[r, 2]
            for a in range(c):
                dx, dy, dz = pos[obs[a], 0] - px, pos[obs[a], 1] - py, pos[obs[a], 2] - pz
                nd = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-300)
                u[a, 0], u[a, 1], u[a, 2] = dx / nd, dy / nd, dz / nd
            paired = False  # a pair of sel already makes the angle: any new observer completes the row
            for a in range(c):
                for b in range(a + 1, c):
                    if u[a, 0] * u[b, 0] + u[a, 1] * u[b, 1] + u[a, 2] * u[b, 2] <= cos_t:
                        paired = True
            wr = w[r]
            for p in range(indptr[r], indptr[r + 1]):
                x = indices[p]
                if data[p] <= 0 or where[x] >= 0:
                    continue
                if paired:
                    out[ch, x] += wr
                    continue
                dx, dy, dz = pos[x, 0] - px, pos[x, 1] - py, pos[x, 2] - pz
                lim = cos_t * math.sqrt(dx * dx + dy * dy + dz * dz)
                for a in range(c):
                    if dx * u[a, 0] + dy * u[a, 1] + dz * u[a, 2] <= lim:
                        out[ch, x] += wr
                        break
    return out.sum(axis=0)


@numba.njit(**_JIT)
def fixed_pairs(fbits, fpos, pts, theta_deg):  # pragma: no cover - compiled
    """(W,) uint64: rows where two fixed cameras both observe and make the angle."""
    r, n_words = fbits.shape
    out = np.zeros(n_words, dtype=np.uint64)
    for wd in range(n_words):
        for a in range(r):
            for b in range(a + 1, r):
                x = fbits[a, wd] & fbits[b, wd] & ~out[wd]
                if x:
                    out[wd] |= _exact_bits(x, wd, fpos[a], fpos[b], pts, theta_deg, math.cos(math.radians(theta_deg)))
    return out


@numba.njit(**_JIT)
def count_bad_pairs(indptr, indices, data, rows, allowed, pos, pts, theta_deg, limit):  # pragma: no cover - compiled
    """Pairs of allowed observers of ``rows`` that do NOT make the angle (the SCIP model's
    conflict rows), summed over the rows; stops as soon as the sum passes ``limit``."""
    cos_t = math.cos(math.radians(theta_deg))
    bad = 0
    for i in range(rows.shape[0]):
        r = rows[i]
        s = indptr[r]
        e = indptr[r + 1]
        for a in range(s, e):
            if data[a] <= 0 or not allowed[indices[a]]:
                continue
            for b in range(a + 1, e):
                if data[b] > 0 and allowed[indices[b]] and not angle_ok(pts[r], pos[indices[a]], pos[indices[b]],
                                                                        theta_deg, cos_t):
                    bad += 1
            if bad > limit:
                return bad
    return bad


@numba.njit(**_JIT)
def column_weights(indptr, indices, data, rows, w_rows, n):  # pragma: no cover - compiled
    """(n,) float64: per column, the summed ``w_rows`` of the rows ``rows`` it observes."""
    out = np.zeros(n)
    for i in range(rows.shape[0]):
        r = rows[i]
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0:
                out[indices[p]] += w_rows[i]
    return out


@numba.njit(**_JIT)
def selected_pattern(indptr, indices, data, rows, cols, n):  # pragma: no cover - compiled
    """(r, s) bool: which of the columns ``cols`` observe (value > 0) each of the rows ``rows``."""
    where = np.full(n, -1, dtype=np.int64)
    for t in range(cols.shape[0]):
        where[cols[t]] = t
    out = np.zeros((rows.shape[0], cols.shape[0]), dtype=np.bool_)
    for i in range(rows.shape[0]):
        r = rows[i]
        for p in range(indptr[r], indptr[r + 1]):
            t = where[indices[p]]
            if t >= 0 and data[p] > 0:
                out[i, t] = True
    return out


# ----------------------------------------------------------------------------------------------
# the same per-row passes on column bitsets (a binary matrix as camplace.visibility.bits.BitMatrix
# holds it: words (n, ceil(m / 64)) uint64, bit i % 64 of word i // 64 = row i)
# ----------------------------------------------------------------------------------------------


@numba.njit(**_JIT)
def row_status_bits_block(lo, hi, words, sel, pos, pts, views, theta_deg, count, ok):  # pragma: no cover - compiled
    """:func:`row_status_bits` of rows ``lo:hi``, written into ``count`` and ``ok``."""
    cos_t = math.cos(math.radians(theta_deg))
    obs = np.empty(sel.shape[0], dtype=np.int64)
    for r in range(lo, hi):
        wd = r >> 6
        bit = np.uint64(1) << np.uint64(r & 63)
        c = 0
        for t in range(sel.shape[0]):
            if words[sel[t], wd] & bit:
                obs[c] = sel[t]
                c += 1
        count[r] = c
        if c < views or c < 2:
            continue
        found = False
        for a in range(c):
            for b in range(a + 1, c):
                if angle_ok(pts[r], pos[obs[a]], pos[obs[b]], theta_deg, cos_t):
                    found = True
                    break
            if found:
                break
        ok[r] = found


@numba.njit(**_JIT)
def row_status_bits(words, m, sel, pos, pts, views, theta_deg):  # pragma: no cover - compiled
    """:func:`row_status` of column bitsets: ``sel`` ascending and distinct (the observers of a row
    are then listed in the order the CSR kernel lists them, so every angle test is the same).
    Reads ``m x len(sel)`` bits instead of every observed pair. (On the pool:
    :func:`row_status_bits_block`.)"""
    count = np.zeros(m, dtype=np.int64)
    ok = np.zeros(m, dtype=np.bool_)
    row_status_bits_block(0, m, words, sel, pos, pts, views, theta_deg, count, ok)
    return count, ok


@numba.njit(**_PJIT)
def gains_bits(words, m, w, sel, pos, pts, views, theta_deg, count, ok, n_chunks):  # pragma: no cover - compiled
    """:func:`gains` of column bitsets, the same float64 numbers: each row's selected observers
    (``sel`` ascending and distinct), unit rays and "already paired" flag first, then per column
    the weights of the rows it would complete, summed per chunk of ``ceil(m / n_chunks)`` rows in
    row order and the chunks added in order, as :func:`gains` sums them."""
    cos_t = math.cos(math.radians(theta_deg))
    n = words.shape[0]
    n_words = words.shape[1]
    s = sel.shape[0]
    where = np.full(n, -1, dtype=np.int64)
    for t in range(s):
        where[sel[t]] = t
    step = (m + n_chunks - 1) // n_chunks
    u = np.zeros((m, max(s, 1), 3))
    c_row = np.zeros(m, dtype=np.int64)
    paired = np.zeros(m, dtype=np.bool_)
    active = np.zeros(n_words, dtype=np.uint64)
    for wd in prange(n_words):
        acc = np.uint64(0)
        for r in range(wd * 64, min(m, wd * 64 + 64)):
            if ok[r] or w[r] <= 0 or count[r] == 0 or count[r] + 1 < views:
                continue
            acc |= np.uint64(1) << np.uint64(r & 63)
            bit = np.uint64(1) << np.uint64(r & 63)
            px, py, pz = pts[r, 0], pts[r, 1], pts[r, 2]
            c = 0
            for t in range(s):
                if words[sel[t], wd] & bit:
                    j = sel[t]
                    dx, dy, dz = pos[j, 0] - px, pos[j, 1] - py, pos[j, 2] - pz
                    nd = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-300)
                    u[r, c, 0], u[r, c, 1], u[r, c, 2] = dx / nd, dy / nd, dz / nd
                    c += 1
            c_row[r] = c
            p_ok = False
            for a in range(c):
                for b in range(a + 1, c):
                    if u[r, a, 0] * u[r, b, 0] + u[r, a, 1] * u[r, b, 1] + u[r, a, 2] * u[r, b, 2] <= cos_t:
                        p_ok = True
            paired[r] = p_ok
        active[wd] = acc
    out = np.zeros(n)
    for x in prange(n):
        if where[x] >= 0:
            continue
        part = np.zeros(n_chunks)
        for wd in range(n_words):
            bits = words[x, wd] & active[wd]
            while bits:
                r = (wd << 6) + np.int64(_ctz(bits))
                bits &= bits - np.uint64(1)
                ch = r // step
                if paired[r]:
                    part[ch] += w[r]
                    continue
                px, py, pz = pts[r, 0], pts[r, 1], pts[r, 2]
                dx, dy, dz = pos[x, 0] - px, pos[x, 1] - py, pos[x, 2] - pz
                lim = cos_t * math.sqrt(dx * dx + dy * dy + dz * dz)
                for a in range(c_row[r]):
                    if dx * u[r, a, 0] + dy * u[r, a, 1] + dz * u[r, a, 2] <= lim:
                        part[ch] += w[r]
                        break
        tot = 0.0
        for ch in range(n_chunks):
            tot += part[ch]
        out[x] = tot
    return out


@numba.njit(**_JIT)
def column_lists(indptr, indices, data, row_id, local, n_local):  # pragma: no cover - compiled
    """The rows that some columns observe (value > 0), column by column, in one pass over the CSR
    matrix, numbered by ``row_id``.

    Parameters
    ----------
    indptr, indices, data
        The (m, n) CSR matrix.
    row_id : (m,) int64
        Number of each row in the output (-1: left out).
    local : (n,) int64
        Index of each wanted column in the output (-1: not wanted).
    n_local : int

    Returns
    -------
    ptr : (n_local + 1,) int64
    rows : (ptr[-1],) int32
        Row numbers of output column ``c``: ``rows[ptr[c]:ptr[c + 1]]``, in matrix order.
    """
    m = indptr.shape[0] - 1
    ptr = np.zeros(n_local + 1, dtype=np.int64)
    for r in range(m):
        if row_id[r] < 0:
            continue
        for p in range(indptr[r], indptr[r + 1]):
            c = local[indices[p]]
            if c >= 0 and data[p] > 0:
                ptr[c + 1] += 1
    for c in range(n_local):
        ptr[c + 1] += ptr[c]
    fill = ptr[:-1].copy()
    rows = np.empty(ptr[n_local], dtype=np.int32)
    for r in range(m):
        if row_id[r] < 0:
            continue
        for p in range(indptr[r], indptr[r + 1]):
            c = local[indices[p]]
            if c >= 0 and data[p] > 0:
                rows[fill[c]] = row_id[r]
                fill[c] += 1
    return ptr, rows


@numba.njit(**_JIT)
def _set_value(ptr, rows, cols, w, campos, pts, views, theta_deg, cos_t, cnt, obs, touched):  # pragma: no cover - compiled
    """Weight of the rows at least ``views`` of the columns ``cols`` observe with a pair making the
    angle (``cnt`` (m,) zero on entry and on exit, ``obs`` (m, s), ``touched`` scratch; int32)."""
    n_t = 0
    for a in range(cols.shape[0]):
        c = cols[a]
        for p in range(ptr[c], ptr[c + 1]):
            r = rows[p]
            if cnt[r] == 0:
                touched[n_t] = r
                n_t += 1
            obs[r, cnt[r]] = c
            cnt[r] += 1
    total = 0.0
    for t in range(n_t):
        r = touched[t]
        c = cnt[r]
        cnt[r] = 0
        if c < views or c < 2:
            continue
        found = False
        for a in range(c):
            for b in range(a + 1, c):
                if angle_ok(pts[r], campos[obs[r, a]], campos[obs[r, b]], theta_deg, cos_t):
                    found = True
                    break
            if found:
                break
        if found:
            total += w[r]
    return total


@numba.njit(**_PJIT)
def set_values(ptr, rows, sets, w, campos, pts, views, theta_deg, n_chunks):  # pragma: no cover - compiled
    """Exact value of every camera set of ``sets``: the weight of the rows that at least ``views``
    of its cameras observe with two of them making the angle (the rule of :func:`row_status`).

    Parameters
    ----------
    ptr, rows
        Rows observed by each local column (:func:`column_lists`; numbers below m).
    sets : (T, s) int64
        Local columns of each set (distinct within a set).
    w : (m,) float64
        Weights of the numbered rows.
    campos : (n_local, 3) float64
        Positions of the local columns.
    pts : (m, 3) float64
        Points of the numbered rows.
    views : int
    theta_deg : float
    n_chunks : int
        Parallel chunks (each with its own (m, s + 1) int32 scratch).

    Returns
    -------
    (T,) float64
    """
    cos_t = math.cos(math.radians(theta_deg))
    n_sets, s = sets.shape
    m = w.shape[0]
    out = np.zeros(n_sets)
    step = (n_sets + n_chunks - 1) // max(n_chunks, 1)
    longest = 0
    for c in range(ptr.shape[0] - 1):
        longest = max(longest, ptr[c + 1] - ptr[c])
    for ch in prange(n_chunks):
        cnt = np.zeros(m, dtype=np.int32)
        obs = np.empty((m, max(s, 1)), dtype=np.int32)
        touched = np.empty(min(m, max(1, s * longest)), dtype=np.int32)
        for i in range(ch * step, min(n_sets, (ch + 1) * step)):
            out[i] = _set_value(ptr, rows, sets[i], w, campos, pts, views, theta_deg, cos_t, cnt, obs, touched)
    return out
