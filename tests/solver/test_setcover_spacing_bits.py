"""Set cover with a minimum distance on column bitsets (issue 32): the coverable rows counted from
the bits and only the rows left to cover made into the bool CSR the SCIP model reads, never the
whole matrix; the same answer as the CSR route and the enumerated cheapest spaced cover."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.api as api
from camplace.errors import CamplaceError
from camplace.solver.api import solve
from camplace.visibility.bits import bits_from_csr
from tests.solver.test_large_k_bits import watch_tocsr


@pytest.fixture(autouse=True)
def _spaced_route_only(monkeypatch):
    """These tests are of the spaced route itself: the relaxation first (api._relaxed_first, a
    proven spaced optimum returned before it) is tested in tests/solver/test_spacing_relaxed.py."""
    monkeypatch.setattr(api, "_relaxation_applies", lambda o: False)


def _cheapest_spaced_cover(dense: np.ndarray, w: np.ndarray, cost: np.ndarray, pos: np.ndarray, dmin: float,
                           fixed: tuple[int, ...]) -> float:
    """Enumeration: the least cost of new columns that, with ``fixed``, cover every row of positive
    weight that the allowed columns observe (allowed: fixed, or not closer than ``dmin`` to a fixed
    one), no two chosen columns (fixed ones included) closer than ``dmin``."""
    n = dense.shape[1]
    free = [j for j in range(n) if j not in fixed and all(np.linalg.norm(pos[j] - pos[f]) >= dmin for f in fixed)]
    need = (w > 0) & (dense[:, free + list(fixed)].sum(axis=1) > 0)
    best = np.inf
    for r in range(len(free) + 1):
        for cols in itertools.combinations(free, r):
            chosen = list(fixed) + list(cols)
            if any(np.linalg.norm(pos[a] - pos[b]) < dmin for a, b in itertools.combinations(chosen, 2)):
                continue
            if np.all(dense[need][:, chosen].sum(axis=1) > 0) if chosen else not need.any():
                best = min(best, float(cost[list(cols)].sum()))
    return best


def _cases(seed: int):
    rng = np.random.default_rng(seed)
    for m, n, dens in [(40, 9, 0.45), (70, 10, 0.4), (25, 8, 0.55), (50, 10, 0.5)]:
        dense = (rng.random((m, n)) < dens).astype(np.float32)
        dense[5] = 0.0  # a row nobody sees: not coverable, not required
        w = np.where(rng.random(m) < 0.15, 0.0, rng.random(m) + 0.1)
        yield dense, w, rng.random((n, 3)) * 5.0, rng.integers(1, 4, n).astype(np.float64)


@pytest.mark.parametrize("fixed", [(), (2,)])
def test_spaced_set_cover_on_bits_equals_csr_and_enumeration(fixed, monkeypatch) -> None:
    found = modelled = 0
    for dense, w, pos, cost in _cases(len(fixed) + 7):
        kw = dict(mode="setcover", costs=cost, min_distance_m=1.5, positions=pos, fixed=fixed)
        try:
            want = _cheapest_spaced_cover(dense, w, cost, pos, 1.5, fixed)
        except ValueError:
            continue
        ref = solve(sp.csr_matrix(dense), w, **kw)
        bits = bits_from_csr(sp.csr_matrix(dense))
        with monkeypatch.context() as mp:
            shapes = watch_tocsr(mp, bits)
            got = solve(bits, w, **kw)
        assert (got.status, got.objective, got.bound) == (ref.status, ref.objective, ref.bound)
        assert got.selected == ref.selected
        if np.isfinite(want):
            found += 1
            assert got.status == "optimal" and got.objective == pytest.approx(want)
            assert all(s[0] < dense.shape[0] for s in shapes)  # (the whole matrix is refused by watch_tocsr)
            modelled += got.stats["matrix"] == "column bitsets (the rows to cover as a bool CSR for the model)"
            chosen = got.selected
            assert all(np.linalg.norm(pos[a] - pos[b]) > 1.5 for a, b in itertools.combinations(chosen, 2))
        else:
            assert got.status == "infeasible"
    assert found >= 2 and modelled >= 1  # the cases hold spaced covers, some with conflicting free pairs


def test_fixed_cameras_too_close_is_one_line_on_bits() -> None:
    dense = np.eye(4, dtype=np.float32)
    pos = np.array([[0, 0, 0], [0.5, 0, 0], [5, 0, 0], [9, 0, 0]], dtype=np.float64)
    with pytest.raises(CamplaceError, match="closer than min_distance_m") as err:
        solve(bits_from_csr(sp.csr_matrix(dense)), np.ones(4), mode="setcover", min_distance_m=1.0, positions=pos,
              fixed=(0, 1))
    assert "\n" not in str(err.value)
