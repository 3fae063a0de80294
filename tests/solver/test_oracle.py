"""The solver tests' oracles: the vectorised enumeration is the definition, bit for bit.

``tests/solver/_oracle.py`` keeps the definitions in plain Python (``*_by_definition``: point by
point, set by set) and computes the same numbers with numpy for the tests; here the two must give
identical floats (``==``, not approx) on random instances with every option they take: each mode,
views, minimum angles (with angles placed exactly on the threshold), fixed and forbidden cameras,
minimum distances, costs, partial covers, float32 / integer / zero weights and empty sets.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from tests.solver._oracle import (
    brute_force_mode,
    brute_force_mode_by_definition,
    brute_force_setcover,
    brute_force_setcover_by_definition,
    mode_objective,
    mode_objective_by_definition,
)


def _instance(seed: int):
    rng = np.random.default_rng(seed)
    m, n = int(rng.integers(0, 14)), int(rng.integers(1, 8))
    dense = (rng.random((m, n)) < rng.choice([0.2, 0.5, 0.8])) * rng.uniform(0.01, 1.0, (m, n))
    if seed % 5 == 0:  # values <= 0 do not observe (quality takes the largest value > 0)
        dense = np.where(rng.random((m, n)) < 0.2, -dense, dense)
    dense = dense.astype(rng.choice([np.float64, np.float32]))
    kind = seed % 4
    w = (rng.uniform(0, 1, m), rng.integers(0, 5, m), rng.uniform(0, 1, m).astype(np.float32), np.full(m, 1 / max(m, 1)))[kind]
    pos = rng.normal(size=(n, 3)) * 3
    pts = rng.normal(size=(m, 3))
    if m and n >= 2:  # an angle exactly on the threshold: camera 1 at 90 degrees from camera 0 about point 0
        u = pos[0] - pts[0]
        v = np.cross(u, [0.3, -0.2, 1.0])
        pos[1] = pts[0] + v
    if n >= 4:  # two cameras exactly 2 apart (a minimum distance of 2 keeps them)
        pos[3] = pos[2] + np.array([2.0, 0.0, 0.0])
    return rng, dense, w, pos, pts


@pytest.mark.parametrize("seed", range(40))
def test_fast_oracles_equal_the_definitions(seed: int) -> None:
    rng, dense, w, pos, pts = _instance(seed)
    n = dense.shape[1]
    fixed = tuple(int(j) for j in rng.choice(n, size=min(n, int(rng.integers(0, 2))), replace=False))
    forbidden = tuple(int(j) for j in rng.choice([j for j in range(n) if j not in fixed] or [0], size=int(rng.integers(0, 2))))
    forbidden = tuple(j for j in forbidden if j not in fixed)
    dmin = (2.0 if seed % 2 else float(rng.choice([0.0, 4.0]))) if seed % 3 == 0 else None
    angle_of_pair = 90.0 if seed % 2 else float(rng.choice([10.0, 30.0, 60.0]))
    kinds = [dict(mode="maxcover"), dict(mode="quality"), dict(mode="setcover"), dict(mode="multiview", views=2),
             dict(mode="multiview", views=1), dict(mode="multiview", views=3),
             dict(mode="multiview", views=2, min_angle_deg=angle_of_pair, pos=pos, pts=pts)]
    compared = 0
    for kw in kinds:
        kw = dict(kw)
        mode = kw.pop("mode")
        for r in range(0, n + 1):
            for cols in itertools.combinations(range(n), r):
                a = mode_objective(dense, w, cols, mode, **kw)
                b = mode_objective_by_definition(dense, w, cols, mode, **kw)
                assert a == b and type(a) is type(b) is float, (mode, kw, cols, a, b)
                compared += 1
        for k in range(0, n + 1):
            opts = dict(kw, fixed=fixed, forbidden=forbidden, dmin=dmin)
            if dmin is not None:
                opts["pos"] = pos
            a = brute_force_mode(dense, w, k, mode, **opts)
            b = brute_force_mode_by_definition(dense, w, k, mode, **opts)
            assert a == b, (mode, opts, k, a, b)
            compared += 1
    costs = (rng.integers(1, 4, n), rng.uniform(0.5, 2.0, n), np.ones(n), rng.uniform(0.5, 2.0, n).astype(np.float32))[seed % 4]
    for frac in (1.0, 0.6):
        opts = dict(fixed=fixed, forbidden=forbidden, pos=pos if dmin is not None else None, dmin=dmin)
        a = brute_force_setcover(dense, w, costs, frac, **opts)
        b = brute_force_setcover_by_definition(dense, w, costs, frac, **opts)
        assert a == b, (frac, opts, a, b)
        compared += 1
    assert compared >= 7 * (2 ** n + n + 1)


def test_the_threshold_angle_is_decided_by_the_definition() -> None:
    """Cameras at exactly 90 degrees about a point: in at 90, out at 90 plus an ulp (no rounding moves it)."""
    pts = np.zeros((1, 3))
    pos = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    dense = np.ones((1, 2))
    w = np.ones(1)
    for angle in (90.0, np.nextafter(90.0, 100.0), 89.99):
        want = mode_objective_by_definition(dense, w, (0, 1), "multiview", 2, angle, pos, pts)
        assert mode_objective(dense, w, (0, 1), "multiview", 2, angle, pos, pts) == want
        assert brute_force_mode(dense, w, 2, "multiview", min_angle_deg=angle, pos=pos, pts=pts) == want
    assert mode_objective(dense, w, (0, 1), "multiview", 2, 90.0, pos, pts) == 1.0
    assert mode_objective(dense, w, (0, 1), "multiview", 2, np.nextafter(90.0, 100.0), pos, pts) == 0.0
