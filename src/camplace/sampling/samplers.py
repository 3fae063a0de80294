"""Candidate-position samplers inside an axis-aligned volume.

``chaotic`` is the thesis's volumetric sampling of chaotic systems made uniform: each axis follows
its own orbit of the logistic map x -> r x (1 - x) with r = 4, whose invariant density is the
arcsine law 1 / (pi sqrt(x (1 - x))); the change of variable u = (2 / pi) asin(sqrt(x)) maps it to
the uniform law on [0, 1]. Orbits are burnt in, decimated (every ``stride``-th iterate, to break
the short-range correlation of successive iterates) and re-seeded from the generator when they hit
a floating-point cycle. ``uniform`` (independent uniform draws) and ``sobol`` (scrambled Sobol,
scipy.stats.qmc) are there for comparison.
"""

from __future__ import annotations

import numba
import numpy as np

from camplace.errors import CamplaceError

from camplace.names import SAMPLERS  # noqa: E402  (one list of the names)


def logistic_orbits(x0: np.ndarray, n: int, *, burn_in: int = 1000, stride: int = 7, r: float = 4.0) -> np.ndarray:
    """Iterate independent logistic-map orbits and return density-corrected uniform values.

    Parameters
    ----------
    x0 : (d,) float64
        Initial states in (0, 1), one per orbit.
    n : int
        Number of values per orbit to return.
    burn_in : int
        Iterates discarded before the first value.
    stride : int
        Keep every ``stride``-th iterate.
    r : float
        Map parameter (4 for the fully chaotic map whose density correction is exact).

    Returns
    -------
    (n, d) float64
        Values in [0, 1], uniform in distribution for r = 4.
    """
    x = np.array(x0, dtype=np.float64).reshape(-1)
    out = _orbits(x, int(n), int(burn_in), int(stride), float(r))
    return (2.0 / np.pi) * np.arcsin(np.sqrt(out))


@numba.njit(cache=True, nogil=True)
def _orbits(x0, n, burn_in, stride, r):  # pragma: no cover - compiled
    """Raw iterates of :func:`logistic_orbits`, (n, d) float64 (compiled: the loop is n x stride
    steps; the same floating-point operations in the same order as numpy's elementwise ones)."""
    x = x0.copy()
    d = x.shape[0]
    out = np.empty((n, d), dtype=np.float64)
    for _ in range(burn_in):
        for j in range(d):
            x[j] = r * x[j] * (1.0 - x[j])
    # In float64 the r = 4 orbit can collapse onto the fixed point 0 (x = 0.5 -> 1 -> 0) or a
    # short cycle; nudge such states deterministically (an irrational rotation of the state).
    for i in range(n):
        for _ in range(stride):
            for j in range(d):
                v = r * x[j] * (1.0 - x[j])
                if v <= 1e-12 or v >= 1.0 - 1e-12:
                    v = np.mod(v + 0.6180339887498949 + 1e-3 * (i + 1), 1.0) * 0.98 + 0.01
                x[j] = v
        out[i] = x
    return out


def sample_unit(kind: str, n: int, dim: int = 3, *, seed: int | None = 0) -> np.ndarray:
    """Sample ``n`` points of the unit cube ``[0, 1]^dim``.

    Parameters
    ----------
    kind : {"chaotic", "uniform", "sobol"}
    n : int
    dim : int
    seed : int or None
        Same seed, same output.

    Returns
    -------
    (n, dim) float64
    """
    if kind not in SAMPLERS:
        raise CamplaceError(f"sampler: unknown sampler {kind!r} (use one of {', '.join(SAMPLERS)})")
    if n < 0:
        raise CamplaceError(f"sampler: number of samples must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        return rng.random((n, dim))
    if kind == "sobol":
        if n == 0:
            return np.empty((0, dim))
        from scipy.stats import qmc  # imported here: scipy.stats costs 0.3 s, the default sampler needs none of it

        sob = qmc.Sobol(d=dim, scramble=True, seed=rng)
        m = int(np.ceil(np.log2(max(n, 1))))
        return sob.random_base2(m)[:n]
    # chaotic: one orbit per axis, random initial states away from the map's fixed points
    x0 = rng.uniform(0.05, 0.95, size=dim)
    return logistic_orbits(x0, n)


def sample_positions(
    kind: str,
    n: int,
    min_m: np.ndarray | tuple[float, float, float],
    max_m: np.ndarray | tuple[float, float, float],
    *,
    seed: int | None = 0,
) -> np.ndarray:
    """Sample ``n`` positions in the open box ``min_m < p < max_m``.

    Parameters
    ----------
    kind : {"chaotic", "uniform", "sobol"}
    n : int
    min_m, max_m : (3,) float64
        Box corners, metres.
    seed : int or None

    Returns
    -------
    (n, 3) float64
    """
    lo = np.asarray(min_m, dtype=np.float64)
    hi = np.asarray(max_m, dtype=np.float64)
    u = sample_unit(kind, n, lo.size, seed=seed)
    # keep strictly inside the open box
    u = np.clip(u, 1e-9, 1.0 - 1e-9)
    return lo + u * (hi - lo)
