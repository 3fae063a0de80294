"""Procedural meshes for instance files: sphere, box, corridor and a seeded bilobed comet.

Every function returns ``(vertices, faces)`` as ``(n, 3) float64`` and ``(m, 3) int64`` arrays in
metres, with consistent winding: counter-clockwise seen from outside (outward normals), except
:func:`corridor`, whose normals point inward (cameras stand inside it). Nothing here knows about
TOML; bad arguments raise :class:`ValueError`.

The icosphere is built here (not taken from trimesh) so that generated geometry, and therefore
every built-in instance, does not change with the trimesh version.
"""

from __future__ import annotations

import math

import numpy as np

from camplace.geometry import box_mesh

__all__ = ["SHAPES", "icosphere", "sphere", "box", "corridor", "bilobed_comet", "volcano", "volcano_height"]

# Icosahedron: 12 vertices (cyclic permutations of (0, +-1, +-phi)) and 20 faces.
_PHI = (1.0 + math.sqrt(5.0)) / 2.0
_ICO_VERTICES = np.array(
    [
        [-1, _PHI, 0], [1, _PHI, 0], [-1, -_PHI, 0], [1, -_PHI, 0],
        [0, -1, _PHI], [0, 1, _PHI], [0, -1, -_PHI], [0, 1, -_PHI],
        [_PHI, 0, -1], [_PHI, 0, 1], [-_PHI, 0, -1], [-_PHI, 0, 1],
    ],
    dtype=np.float64,
)  # fmt: skip
_ICO_FACES = np.array(
    [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ],
    dtype=np.int64,
)  # fmt: skip


def _orient_outward(vertices: np.ndarray, faces: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Flip faces of a convex mesh so their normals point away from ``centre`` (an interior point)."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.einsum("ij,ij->i", normals, tri.mean(axis=1) - centre) < 0
    out = faces.copy()
    out[inward] = out[inward][:, ::-1]
    return out


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: an icosahedron whose triangles are split in 4, ``subdivisions`` times.

    Parameters
    ----------
    subdivisions : int
        0 gives the icosahedron (12 vertices); each step multiplies the face count by 4
        (``20 * 4**s`` faces, ``10 * 4**s + 2`` vertices).

    Returns
    -------
    vertices : (n, 3) float64
        Unit vectors.
    faces : (m, 3) int64
        Outward winding.
    """
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or subdivisions < 0:
        raise ValueError(f"subdivisions must be an int >= 0, got {subdivisions!r}")
    v = _ICO_VERTICES / np.linalg.norm(_ICO_VERTICES, axis=1, keepdims=True)
    f = _orient_outward(v, _ICO_FACES, np.zeros(3))
    for _ in range(int(subdivisions)):
        n = len(v)
        # Edges a-b, b-c, c-a of every face; each undirected edge gets one midpoint vertex.
        edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[unique[:, 0]] + v[unique[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        v = np.vstack([v, mid])
        m = (np.asarray(inverse).reshape(-1, 3) + n).astype(np.int64)  # ab, bc, ca per face
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
        f = np.concatenate(
            [
                np.stack([a, ab, ca], axis=1),
                np.stack([b, bc, ab], axis=1),
                np.stack([c, ca, bc], axis=1),
                np.stack([ab, bc, ca], axis=1),
            ]
        )
    return np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(f, dtype=np.int64)


def _positive(name: str, value: float) -> float:
    x = float(value)
    if not math.isfinite(x) or x <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return x


def _size3(size_m) -> np.ndarray:
    s = np.asarray(size_m, dtype=np.float64)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"size_m must be 3 finite numbers > 0, got {size_m!r}")
    return s


def sphere(radius_m: float = 0.5, subdivisions: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere of radius ``radius_m`` centred at the origin, outward normals.

    Parameters
    ----------
    radius_m : float
        > 0, metres.
    subdivisions : int
        1..7.
    """
    r = _positive("radius_m", radius_m)
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or not 1 <= subdivisions <= 7:
        raise ValueError(f"subdivisions must be an int in 1..7, got {subdivisions!r}")
    v, f = icosphere(int(subdivisions))
    return v * r, f


def box(size_m) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of edge lengths ``size_m`` (x, y, z), centred at the origin, outward normals."""
    s = _size3(size_m)
    return box_mesh(-0.5 * s, 0.5 * s)


def corridor(size_m) -> tuple[np.ndarray, np.ndarray]:
    """Closed box spanning ``[0, size]`` on every axis with INWARD normals (floor, ceiling, walls, ends).

    Cameras stand inside; every side faces the interior. Its signed volume is negative.
    """
    s = _size3(size_m)
    v, f = box_mesh(np.zeros(3), s)
    return v, np.ascontiguousarray(f[:, ::-1])


# Lobes of the comet in relative units (67P: big lobe about 4.1 x 3.3 x 1.8 km, small lobe about
# 2.6 x 2.3 x 1.8 km, the small "head" raised above the big "body"). Both ellipsoids contain the
# origin (the "neck") for every size jitter used below, so their union is star-shaped from it.
# Centre, semi-axes.
_BIG_LOBE = (np.array([-1.50, 0.00, -0.50]), np.array([2.00, 1.80, 1.10]))
_SMALL_LOBE = (np.array([0.85, 0.00, 0.60]), np.array([1.30, 1.30, 1.05]))
_NOISE_TERMS = 8


def _ray_to_ellipsoid(u: np.ndarray, centre: np.ndarray, semi: np.ndarray) -> np.ndarray:
    """Distance t > 0 along unit directions ``u`` (n, 3) from the origin (inside) to the ellipsoid surface."""
    a = np.sum((u / semi) ** 2, axis=1)
    b = u @ (centre / semi**2)
    c = float(np.sum((centre / semi) ** 2)) - 1.0
    if not c < 0:  # pragma: no cover - the lobe constants guarantee it
        raise AssertionError("the origin must be inside every lobe")
    return (b + np.sqrt(b * b - a * c)) / a


def bilobed_comet(
    length_m: float = 0.6, seed: int = 0, subdivisions: int = 5, noise: float = 0.06
) -> tuple[np.ndarray, np.ndarray]:
    """A seeded "rubber duck" comet like 67P/Churyumov-Gerasimenko: two overlapping ellipsoidal lobes.

    Icosphere directions ``u`` get radius ``r(u) = max`` over the two lobes of the distance from the
    origin to the lobe's surface along ``u`` (exact for a union of convex sets containing the origin),
    times ``1 + noise * field(u)`` with ``field(u) = sum_j a_j sin(f_j (d_j . u) + phi_j)``,
    ``sum_j a_j = 1`` (so ``|field| <= 1``). The lobe sizes are jittered by a few percent (at most 5 %). All random
    numbers come from one ``numpy.random.default_rng(seed)``. The mesh is then translated so its
    bounding-box centre is at the origin and scaled so its longest bounding-box edge is ``length_m``.

    The surface is a radial graph over the sphere, so it is watertight, free of self-intersections
    and has outward normals by construction.

    Parameters
    ----------
    length_m : float
        > 0, longest bounding-box edge, metres.
    seed : int
        >= 0.
    subdivisions : int
        2..7 (5 gives 20,480 triangles).
    noise : float
        Relative surface roughness amplitude, 0..0.3.

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    """
    length = _positive("length_m", length_m)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an int >= 0, got {seed!r}")
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or not 2 <= subdivisions <= 7:
        raise ValueError(f"subdivisions must be an int in 2..7, got {subdivisions!r}")
    nz = float(noise)
    if not (math.isfinite(nz) and 0.0 <= nz <= 0.3):
        raise ValueError(f"noise must be in 0..0.3, got {noise!r}")

    rng = np.random.default_rng(int(seed))
    big_scale = rng.uniform(0.97, 1.03, size=3)
    small_scale = rng.uniform(0.95, 1.05, size=3)
    d = rng.standard_normal((_NOISE_TERMS, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    freq = rng.uniform(1.0, 4.0, size=_NOISE_TERMS)
    phase = rng.uniform(0.0, 2.0 * math.pi, size=_NOISE_TERMS)
    amp = rng.uniform(0.5, 1.0, size=_NOISE_TERMS)
    amp /= amp.sum()

    u, faces = icosphere(int(subdivisions))
    r = np.maximum(
        _ray_to_ellipsoid(u, _BIG_LOBE[0], _BIG_LOBE[1] * big_scale),
        _ray_to_ellipsoid(u, _SMALL_LOBE[0], _SMALL_LOBE[1] * small_scale),
    )
    field = np.sin((u @ d.T) * freq + phase) @ amp
    v = u * (r * (1.0 + nz * field))[:, None]

    lo, hi = v.min(axis=0), v.max(axis=0)
    v = (v - (lo + hi) / 2.0) * (length / float(np.max(hi - lo)))
    return np.ascontiguousarray(v, dtype=np.float64), faces


# Shape name -> (function, {parameter: default}); a default of None means required.
def volcano_height(
    x: np.ndarray,
    y: np.ndarray,
    height_m: float,
    base_radius_m: float,
    crater_radius_m: float,
    crater_depth_m: float,
) -> np.ndarray:
    """Height of the volcano surface at (x, y): a cone with a crater, flat ground outside.

    z = height * (1 - r / base_radius) for crater_radius <= r <= base_radius (0 beyond); inside the
    crater, z = rim - crater_depth * (1 - r / crater_radius) with rim = height * (1 - crater_radius /
    base_radius): a funnel whose floor lies crater_depth below the rim.

    Parameters
    ----------
    x, y : (...) float64

    Returns
    -------
    (...) float64
    """
    r = np.hypot(x, y)
    cone = height_m * np.clip(1.0 - r / base_radius_m, 0.0, None)
    rim = height_m * (1.0 - crater_radius_m / base_radius_m)
    crater = rim - crater_depth_m * (1.0 - r / crater_radius_m)
    return np.where(r < crater_radius_m, crater, cone)


def volcano(
    size_m=(400.0, 400.0),
    height_m: float = 80.0,
    base_radius_m: float = 150.0,
    crater_radius_m: float = 25.0,
    crater_depth_m: float = 20.0,
    cells: int = 100,
) -> tuple[np.ndarray, np.ndarray]:
    """Heightfield terrain: a cone with a crater on flat ground, centred at the origin, z up.

    A regular grid of ``cells x cells`` squares over ``size_m`` (x, y), two triangles each,
    normals up; heights from :func:`volcano_height`. An open surface: pair it with
    ``ground = true`` so that no camera is placed under it.
    """
    sx, sy = float(size_m[0]), float(size_m[1])
    for name, v in (("size_m", min(sx, sy)), ("height_m", height_m), ("base_radius_m", base_radius_m),
                    ("crater_radius_m", crater_radius_m)):
        if not v > 0:
            raise ValueError(f"{name} must be > 0")
    if not crater_radius_m < base_radius_m:
        raise ValueError("crater_radius_m must be smaller than base_radius_m")
    if crater_depth_m < 0:
        raise ValueError("crater_depth_m must be >= 0")
    if cells < 2:
        raise ValueError("cells must be >= 2")
    xs = np.linspace(-sx / 2, sx / 2, cells + 1)
    ys = np.linspace(-sy / 2, sy / 2, cells + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    gz = volcano_height(gx, gy, height_m, base_radius_m, crater_radius_m, crater_depth_m)
    vertices = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    idx = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    # counter-clockwise seen from above (+z): (a, b, c) and (a, c, d) with x = first index
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]).astype(np.int64)
    return vertices, faces


SHAPES: dict[str, tuple] = {
    "sphere": (sphere, {"radius_m": 0.5, "subdivisions": 4}),
    "box": (box, {"size_m": None}),
    "corridor": (corridor, {"size_m": None}),
    "bilobed-comet": (bilobed_comet, {"length_m": 0.6, "seed": 0, "subdivisions": 5, "noise": 0.06}),
    "volcano": (
        volcano,
        {"size_m": (400.0, 400.0), "height_m": 80.0, "base_radius_m": 150.0, "crater_radius_m": 25.0,
         "crater_depth_m": 20.0, "cells": 100},
    ),
}
