"""Deterministic structured max-coverage instances for solver tests and benchmarks.

The matrices mimic the product's visibility matrices: points on an object surface (a unit sphere or
a bilobed union of two unit spheres) with outward normals, and candidate cameras scattered around
it. Neighbouring candidates see nearly identical point sets, which is what makes naive
branch-and-bound explode and what the exact engine is designed for.

This module uses only numpy/scipy (no geometry library): for a unit sphere, "the point faces the
camera" is exact visibility (a spherical cap of area fraction ``(1 - 1/d) / 2``). For the bilobed
shape the other lobe can also occlude a point; that is tested with an exact segment/sphere test.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp

__all__ = ["structured_instance", "random_instance"]

log = logging.getLogger(__name__)

_LOBE_OFFSET = 0.8  # bilobed: unit spheres centred at (+-0.8, 0, 0)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _surface_points(rng: np.random.Generator, m: int, shape: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample ``m`` surface points.

    Returns
    -------
    points : (m, 3) float64
    normals : (m, 3) float64
    lobe : (m,) int64
        Index of the sphere each point lies on (0 for the plain sphere).
    """
    if shape == "sphere":
        n = _unit(rng.standard_normal((m, 3)))
        return n.copy(), n, np.zeros(m, dtype=np.int64)
    if shape != "bilobed":
        raise ValueError(f"unknown shape {shape!r} (use 'sphere' or 'bilobed')")
    centres = np.array([[-_LOBE_OFFSET, 0.0, 0.0], [_LOBE_OFFSET, 0.0, 0.0]])
    pts: list[np.ndarray] = []
    nrm: list[np.ndarray] = []
    lob: list[np.ndarray] = []
    have = 0
    while have < m:
        batch = 2 * (m - have) + 16
        n = _unit(rng.standard_normal((batch, 3)))
        which = rng.integers(0, 2, size=batch)
        p = centres[which] + n
        other = centres[1 - which]
        keep = np.linalg.norm(p - other, axis=1) > 1.0  # not buried inside the other lobe
        pts.append(p[keep])
        nrm.append(n[keep])
        lob.append(which[keep])
        have += int(keep.sum())
    return (np.concatenate(pts)[:m], np.concatenate(nrm)[:m], np.concatenate(lob)[:m].astype(np.int64))


def _camera_positions(
    rng: np.random.Generator, n: int, corridor: bool, dmin: float, dmax: float, centres: np.ndarray
) -> np.ndarray:
    """(n, 3) float64 camera centres; corridor cameras keep 1.3 away from every lobe centre."""
    if not corridor:
        d = _unit(rng.standard_normal((n, 3)))
        r = rng.uniform(dmin, dmax, size=n)
        return d * r[:, None]
    out: list[np.ndarray] = []
    have = 0
    while have < n:
        batch = 2 * (n - have) + 16
        c = np.column_stack(
            [rng.uniform(-dmax, dmax, batch), rng.uniform(-1.5, 1.5, batch), rng.uniform(-1.5, 1.5, batch)]
        )
        keep = np.all(np.linalg.norm(c[:, None, :] - centres[None, :, :], axis=2) > 1.3, axis=1)
        out.append(c[keep])
        have += int(keep.sum())
    return np.concatenate(out)[:n]


def structured_instance(
    m: int,
    n: int,
    *,
    seed: int = 0,
    shape: str = "sphere",
    corridor: bool = False,
    fov_deg: float | None = None,
    max_range: float | None = None,
    dmin: float = 1.5,
    dmax: float = 15.0,
) -> tuple[sp.csr_matrix, np.ndarray]:
    """Build a structured visibility matrix and equal point weights.

    Parameters
    ----------
    m : int
        Number of surface points (rows).
    n : int
        Number of candidate cameras (columns).
    seed : int
        Seed for ``numpy.random.default_rng`` (used once; the output is deterministic).
    shape : {"sphere", "bilobed"}
        Unit sphere, or the union of two unit spheres centred at (+-0.8, 0, 0) (with occlusion).
    corridor : bool
        If True, cameras lie in the box ``|x| <= dmax, |y|, |z| <= 1.5`` outside a ball of radius 1.3;
        otherwise at uniformly random directions and distances ``dmin..dmax`` from the origin.
    fov_deg : float, optional
        Full field-of-view angle; each camera looks at the origin and sees a point only if the ray
        to it is within ``fov_deg / 2`` of the optical axis.
    max_range : float, optional
        Maximum camera-to-point distance.
    dmin, dmax : float
        Camera distance range (``dmax`` is also the corridor half-length).

    Returns
    -------
    matrix : (m, n) scipy.sparse.csr_matrix of float64
        Observation quality in (0, 1] (cosine of the incidence angle, floored at 1e-3) where the
        camera sees the point, 0 elsewhere.
    weights : (m,) float64
        Equal weights ``1 / m``.
    """
    if m < 1 or n < 1:
        raise ValueError("m and n must be >= 1")
    rng = np.random.default_rng(seed)
    pts, nrm, lobe = _surface_points(rng, m, shape)
    centres = np.array([[-_LOBE_OFFSET, 0.0, 0.0], [_LOBE_OFFSET, 0.0, 0.0]])
    cams = _camera_positions(rng, n, corridor, dmin, dmax, centres if shape == "bilobed" else np.zeros((1, 3)))
    cos_half = None if fov_deg is None else float(np.cos(np.radians(fov_deg) / 2.0))

    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    chunk = max(1, int(4_000_000 // max(m, 1)))
    for j0 in range(0, n, chunk):
        c = cams[j0 : j0 + chunk]  # (b, 3)
        ray = c[None, :, :] - pts[:, None, :]  # (m, b, 3) point -> camera
        dist = np.linalg.norm(ray, axis=2)
        cosang = np.einsum("mbk,mk->mb", ray, nrm) / dist
        vis = cosang > 0.0
        if shape == "bilobed":
            # Occlusion by the other lobe: does the segment point->camera meet that sphere?
            oc = centres[1 - lobe]  # (m, 3)
            f = pts - oc  # (m, 3)
            a = dist**2
            b = 2.0 * np.einsum("mbk,mk->mb", ray, f)
            cc = np.einsum("mk,mk->m", f, f)[:, None] - 1.0
            disc = b * b - 4.0 * a * cc
            sq = np.sqrt(np.maximum(disc, 0.0))
            t1 = (-b - sq) / (2.0 * a)
            t2 = (-b + sq) / (2.0 * a)
            hit = (disc > 0.0) & (t2 > 1e-9) & (t1 < 1.0)
            vis &= ~hit
        if cos_half is not None:
            axis = -c / np.linalg.norm(c, axis=1, keepdims=True)  # (b, 3) camera looks at origin
            cos_fov = -np.einsum("mbk,bk->mb", ray, axis) / dist
            vis &= cos_fov >= cos_half
        if max_range is not None:
            vis &= dist <= max_range
        r, cj = np.nonzero(vis)
        rows.append(r)
        cols.append(cj + j0)
        vals.append(np.maximum(cosang[r, cj], 1e-3))
    mat = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(m, n), dtype=np.float64
    )
    weights = np.full(m, 1.0 / m)
    log.debug("structured instance %dx%d (%s): nnz=%d", m, n, shape, mat.nnz)
    return mat, weights


def random_instance(
    m: int,
    n: int,
    *,
    seed: int = 0,
    density: float = 0.2,
    duplicate_cols: int = 0,
    duplicate_rows: int = 0,
    zero_weights: int = 0,
    integer_weights: bool = False,
) -> tuple[sp.csr_matrix, np.ndarray]:
    """Small unstructured instance with optional near-duplicate columns, repeated rows, zero weights.

    Parameters
    ----------
    m, n : int
        Shape.
    seed : int
        Seed for ``numpy.random.default_rng``.
    density : float
        Probability that an entry is non-zero.
    duplicate_cols : int
        Number of extra columns that copy an existing column with one entry flipped.
    duplicate_rows : int
        Number of rows overwritten by a copy of another row.
    zero_weights : int
        Number of rows given weight 0.
    integer_weights : bool
        Weights in {1, .., 5} instead of uniform (0, 1].

    Returns
    -------
    matrix : (m, n + duplicate_cols) scipy.sparse.csr_matrix of float64
    weights : (m,) float64
    """
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n)) < density) * rng.uniform(0.05, 1.0, size=(m, n))
    extra = []
    for _ in range(duplicate_cols):
        src = dense[:, rng.integers(0, n)].copy()
        i = rng.integers(0, m)
        src[i] = 0.0 if src[i] > 0 else 0.5
        extra.append(src)
    if extra:
        dense = np.column_stack([dense] + extra)
    for _ in range(duplicate_rows):
        dense[rng.integers(0, m)] = dense[rng.integers(0, m)]
    w = rng.integers(1, 6, size=m).astype(np.float64) if integer_weights else rng.uniform(0.0, 1.0, size=m)
    if zero_weights:
        w[rng.choice(m, size=min(zero_weights, m), replace=False)] = 0.0
    return sp.csr_matrix(dense), w
