"""The exact angle engine (multiview with ``min_angle_deg``) against enumeration, its time limit, and
the memory estimates that make every engine / model fall back (or stop) before allocating."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import camplace.solver.api as modes
import camplace.solver.engines.angle.search as ae
import camplace.solver.engines.mip.mode_models as models
import camplace.solver.routes as routes
from camplace.errors import CamplaceError
from camplace.solver import solve_maxcover
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import memory_budget, memory_budget_bytes
from camplace.solver.api import solve
from tests.solver._oracle import ExpiringDeadline, brute_force_mode, mode_objective, solve_deadline

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
_TINY = 4096  # bytes: no engine or model fits


# ---- oracle: every camera set, angles from arctan2 (independent of the solver's formula) -------


def _pair_ok(dense: np.ndarray, pos: np.ndarray, pts: np.ndarray, angle_deg: float) -> np.ndarray:
    """(m, n, n) bool: both cameras observe the point and their rays make at least the angle."""
    u = pos[None, :, :] - pts[:, None, :]
    cross = np.linalg.norm(np.cross(u[:, :, None, :], u[:, None, :, :]), axis=3)
    dot = np.einsum("iad,ibd->iab", u, u)
    ang = np.degrees(np.arctan2(cross, dot))
    obs = dense > 0
    good = (ang >= angle_deg) & obs[:, :, None] & obs[:, None, :]
    good[:, np.arange(pos.shape[0]), np.arange(pos.shape[0])] = False
    return good


def _enumerate(dense, w, pos, pts, k, views, angle_deg, fixed=(), forbidden=()) -> tuple[float, np.ndarray]:
    """Best value over every k new cameras, and the value of each set (vectorised enumeration)."""
    good = _pair_ok(dense, pos, pts, angle_deg)
    obs = dense > 0
    free = [j for j in range(dense.shape[1]) if j not in fixed and j not in forbidden]
    vals = []
    for new in itertools.combinations(free, k):
        cols = list(fixed) + list(new)
        cnt = obs[:, cols].sum(axis=1)
        pair = good[:, cols][:, :, cols].any(axis=(1, 2))
        vals.append(float(w[(cnt >= views) & pair].sum()))
    vals = np.asarray(vals)
    return float(vals.max()), vals


def _value(dense, w, pos, pts, cols, views, angle_deg, good=None) -> float:
    """The value of camera set ``cols``; ``good``: ``_pair_ok(dense, pos, pts, angle_deg)`` when the caller has it."""
    good = _pair_ok(dense, pos, pts, angle_deg) if good is None else good
    cols = list(cols)
    cnt = (dense[:, cols] > 0).sum(axis=1)
    return float(w[(cnt >= views) & good[:, cols][:, :, cols].any(axis=(1, 2))].sum())


def _sphere_instance(m: int, n: int, seed: int, spread: float = 1.0):
    """Points on a unit sphere, cameras around it at 2..6 units; a camera observes the points facing
    it (and in its field of view when ``spread < 1``)."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(m, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos = d * rng.uniform(2.0, 6.0, size=(n, 1))
    ray = pos[None, :, :] - pts[:, None, :]
    facing = np.einsum("id,ijd->ij", pts, ray) > 0
    cos_fov = np.einsum("jd,ijd->ij", d, ray) / np.linalg.norm(ray, axis=2)  # camera axis -d, ray to it
    seen = facing & (cos_fov >= 1.0 - spread)
    w = rng.integers(1, 4, size=m).astype(float) if seed % 2 else np.full(m, 1.0 / m)
    return seen.astype(float), w, pos, pts


# ---- exactness --------------------------------------------------------------------------------


@st.composite
def _small(draw):
    n = draw(st.integers(2, 9))
    m = draw(st.integers(1, 18))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    density = draw(st.sampled_from([0.3, 0.6, 0.9]))
    dense = (rng.random((m, n)) < density) * rng.uniform(0.1, 1.0, size=(m, n))
    if draw(st.booleans()) and n >= 3:
        dense[:, 1] = dense[:, 0]
    w = rng.integers(0, 4, size=m).astype(float) if draw(st.booleans()) else rng.uniform(0.0, 1.0, size=m)
    pos = rng.normal(size=(n, 3)) * 3.0
    if draw(st.booleans()) and n >= 3:
        pos[2] = pos[0]  # two poses at one position: they never make an angle
    pts = rng.normal(size=(m, 3))
    return dense, w, pos, pts


@settings(max_examples=60, **_SETTINGS)
@given(inst=_small(), data=st.data())
def test_angle_engine_equals_enumeration(inst, data) -> None:
    dense, w, pos, pts = inst
    n = dense.shape[1]
    views = data.draw(st.integers(2, 3))
    angle = data.draw(st.sampled_from([0.0, 17.3, 41.9, 88.1]))
    fixed = tuple(sorted(data.draw(st.sets(st.integers(0, n - 1), max_size=2))))
    forbidden = tuple(sorted(data.draw(st.sets(st.integers(0, n - 1), max_size=2)) - set(fixed)))
    free = n - len(fixed) - len(forbidden)
    if free < 1:
        return
    k = data.draw(st.integers(1, min(3, free)))
    res = solve(dense, w, k, mode="multiview", views=views, min_angle_deg=angle, positions=pos, points=pts,
                fixed=fixed, forbidden=forbidden, engine="exact")
    best = brute_force_mode(dense, w, k, "multiview", views=views, min_angle_deg=angle, pos=pos, pts=pts,
                            fixed=fixed, forbidden=forbidden)
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert res.engine == "exact" and res.status == "optimal"
    sel = res.selected
    assert set(fixed) <= set(sel) and not set(forbidden) & set(sel) and len(sel) == len(set(sel)) == len(fixed) + k
    assert res.objective == pytest.approx(mode_objective(dense, w, sel, "multiview", views, angle, pos, pts), abs=tol)
    assert res.objective == pytest.approx(best, abs=tol)
    assert res.bound == res.objective


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_angle_engine_structured_equals_enumeration(seed) -> None:
    """Several 64-row blocks, opposite points (cameras around a sphere), fixed and forbidden cameras."""
    dense, w, pos, pts = _sphere_instance(300, 16, seed, spread=1.0 if seed < 2 else 0.03)
    angle = (20.0, 35.0, 12.5, 50.0)[seed]
    fixed = ((), (3,), (), (5,))[seed]
    forbidden = ((), (7, 8), (1,), ())[seed]
    k = 3 if not fixed else 2
    best, _ = _enumerate(dense, w, pos, pts, k, 2, angle, fixed, forbidden)
    res = solve(sp.csr_matrix(dense), w, k, mode="multiview", views=2, min_angle_deg=angle, positions=pos, points=pts,
                fixed=fixed, forbidden=forbidden, engine="auto")
    assert res.engine == "exact" and res.status == "optimal"
    assert set(fixed) <= set(res.selected) and not set(forbidden) & set(res.selected)
    assert res.objective == pytest.approx(best, rel=1e-9)
    assert _value(dense, w, pos, pts, res.selected, 2, angle) == pytest.approx(best, rel=1e-9)
    es = res.stats["engine_stats"]
    assert es["words"] >= 5
    if seed < 2:
        assert es["search"] == "opposite pairs"  # cameras all around: many opposite points


def test_angle_engine_three_views() -> None:
    dense, w, pos, pts = _sphere_instance(200, 12, 5)
    best, _ = _enumerate(dense, w, pos, pts, 4, 3, 25.0)
    res = solve(dense, w, 4, mode="multiview", views=3, min_angle_deg=25.0, positions=pos, points=pts, engine="exact")
    assert res.status == "optimal"
    assert res.objective == pytest.approx(best, rel=1e-9)


# ---- time limit -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def medium():
    dense, w, pos, pts = _sphere_instance(400, 36, 11)
    best, vals = _enumerate(dense, w, pos, pts, 3, 2, 20.0)
    return dense, w, pos, pts, best


@pytest.mark.parametrize("checks", [0, 1, 2, 5, 9])
def test_angle_engine_interrupted_keeps_a_valid_bound(monkeypatch, medium, checks) -> None:
    dense, w, pos, pts, best = medium
    solve_deadline(monkeypatch, ExpiringDeadline(checks))  # the solve's one deadline
    monkeypatch.setattr(ae, "_BATCH", 4)
    monkeypatch.setattr(ae, "_CHUNK", 2)
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, engine="exact")
    v = _value(dense, w, pos, pts, res.selected, 2, 20.0)
    assert res.objective == pytest.approx(v, rel=1e-9)
    assert res.bound >= best * (1 - 1e-9) and best >= v * (1 - 1e-9)
    assert res.status in ("optimal", "feasible")
    if res.status == "optimal":
        assert v == pytest.approx(best, rel=1e-9)


def test_angle_engine_tiny_time_limit(medium) -> None:
    dense, w, pos, pts, best = medium
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, engine="exact",
                time_limit_s=1e-6)
    assert res.status in ("optimal", "feasible") and len(res.selected) == 3
    assert res.bound >= best * (1 - 1e-9) >= res.objective * (1 - 1e-9) - 1e-12
    assert res.objective == pytest.approx(_value(dense, w, pos, pts, res.selected, 2, 20.0), rel=1e-9)


def test_angle_engine_frontier_cap_keeps_a_valid_bound(monkeypatch, medium) -> None:
    dense, w, pos, pts, best = medium
    monkeypatch.setattr(ae, "_FRONTIER_MAX", 3)
    monkeypatch.setattr(ae, "_FRONTIER_MIN", 3)
    monkeypatch.setattr(ae, "_DEPTH_FIRST_SHARE", 0.7)
    monkeypatch.setattr(ae, "_CHUNK", 2)
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, engine="exact")
    assert res.bound >= best * (1 - 1e-9) >= res.objective * (1 - 1e-9) - 1e-12


# ---- memory: estimates before allocating ------------------------------------------------------


def _forbid(monkeypatch, module, name: str) -> None:
    def boom(*args, **kwargs):
        raise AssertionError(f"{name} allocated despite the memory budget")

    monkeypatch.setattr(module, name, boom)


def test_budget_context_caps_the_budget() -> None:
    free = memory_budget_bytes()
    with memory_budget(_TINY):
        assert memory_budget_bytes() == _TINY
        with memory_budget(None), memory_budget(2 * _TINY):  # nested caps only tighten
            assert memory_budget_bytes() == _TINY
    with memory_budget(None):
        assert memory_budget_bytes() > _TINY
    assert memory_budget_bytes() > _TINY and abs(memory_budget_bytes() - free) < free
    with pytest.raises(CamplaceError):
        with memory_budget(0):
            pass


def test_angle_model_estimate_counts_the_conflict_rows() -> None:
    """The SCIP model's size is known before it is built: witness variables and one row per pair
    of observers closer than the angle."""
    dense, w, pos, pts = _sphere_instance(80, 10, 4)
    q = sp.csr_matrix(dense)
    free = np.arange(10)
    good = _pair_ok(dense, pos, pts, 30.0)
    obs = dense > 0
    s = obs.sum(axis=1)
    live = (w > 0) & (s >= 2)
    a, b = np.triu_indices(10, 1)
    bad = int((obs[:, a] & obs[:, b] & ~good[:, a, b]).sum(axis=1)[live].sum())
    n_vars, n_rows, nnz = models.model_size(q, q, w, w, "multiview", 2, 30.0, pos, pts, (), free,
                                            np.zeros((0, 2), dtype=np.int64), 1 << 40)
    assert n_vars == 10 + int((s[live] + 1).sum())
    assert n_rows == 1 + int((s[live] + 1).sum()) + bad
    assert nnz == 10 + int((3 * s[live] + 1).sum()) + 2 * bad
    model, *_ = models.build_model(q, q, w, w, np.zeros(80), 3, "multiview", 2, 30.0, pos, pts, (), free,
                                   np.zeros((0, 2), dtype=np.int64), 0.0, Deadline(None))
    assert model.n_vars <= n_vars and len(model.rows) <= n_rows  # points without any good pair are skipped
    assert sum(r.idx.size for r in model.rows) <= nnz


def test_angle_model_over_budget_falls_back_without_building(monkeypatch) -> None:
    dense, w, pos, pts = _sphere_instance(120, 9, 6)
    _forbid(monkeypatch, routes, "build_model")
    _forbid(monkeypatch, ae.K, "build_bits")
    best = brute_force_mode(dense, w, 5, "multiview", min_angle_deg=30.0, pos=pos, pts=pts)
    res = solve(dense, w, 5, mode="multiview", min_angle_deg=30.0, positions=pos, points=pts,
                memory_budget_bytes=_TINY)  # auto, k = 5: SCIP, then the angle engine, then greedy
    assert res.status == "feasible" and "memory_fallback" in res.stats
    assert "GiB" in res.stats["memory_fallback"]
    assert res.bound >= best * (1 - 1e-9) >= res.objective * (1 - 1e-9) - 1e-12
    assert res.objective == pytest.approx(mode_objective(dense, w, res.selected, "multiview", 2, 30.0, pos, pts))
    for engine in ("mip", "cpsat", "exact"):
        with pytest.raises(CamplaceError) as ei:
            solve(dense, w, 3, mode="multiview", min_angle_deg=30.0, positions=pos, points=pts, engine=engine,
                  memory_budget_bytes=_TINY)
        assert "\n" not in str(ei.value) and "GiB" in str(ei.value)


def test_angle_engine_over_budget_auto_uses_the_model(monkeypatch) -> None:
    """k = 3: the angle engine does not fit in the budget, the (small) SCIP model does."""
    dense, w, pos, pts = _sphere_instance(60, 8, 7)
    _forbid(monkeypatch, ae.K, "build_bits")
    monkeypatch.setattr(ae, "angle_bytes", lambda *a: 1 << 50)
    res = solve(dense, w, 3, mode="multiview", min_angle_deg=25.0, positions=pos, points=pts)
    best = brute_force_mode(dense, w, 3, "multiview", min_angle_deg=25.0, pos=pos, pts=pts)
    assert res.engine == "mip" and "memory_fallback" in res.stats
    assert res.status == "optimal" and res.objective == pytest.approx(best)


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
def test_general_models_over_budget_fall_back_or_stop(monkeypatch, mode) -> None:
    rng = np.random.default_rng(8)
    dense = (rng.random((50, 10)) < 0.4) * rng.uniform(0.1, 1.0, (50, 10))
    w = rng.uniform(0.0, 1.0, 50)
    pos = rng.normal(size=(10, 3)) * 3
    _forbid(monkeypatch, routes, "build_model")
    assert modes.conflict_pairs(pos, 3.0).shape[0] > 0  # the general model (with conflict rows)
    best = brute_force_mode(dense, w, 3, mode, fixed=(8,), pos=pos, dmin=3.0)
    res = solve(dense, w, 3, mode=mode, fixed=(8,), positions=pos, min_distance_m=3.0, memory_budget_bytes=_TINY)
    assert "GiB" in res.stats["memory_fallback"]
    assert res.status == "feasible" or (res.status == "optimal" and res.objective == pytest.approx(best))
    assert all(np.linalg.norm(pos[a] - pos[b]) >= 3.0 for a, b in itertools.combinations(res.selected, 2))
    assert res.bound >= best * (1 - 1e-9) >= res.objective * (1 - 1e-9) - 1e-12
    with pytest.raises(CamplaceError) as ei:
        solve(dense, w, 3, mode=mode, fixed=(8,), positions=pos, min_distance_m=3.0, engine="mip",
              memory_budget_bytes=_TINY)
    assert "\n" not in str(ei.value) and "GiB" in str(ei.value)


def test_maxcover_engines_over_budget(monkeypatch) -> None:
    from ortools.linear_solver import linear_solver_pb2
    from ortools.sat.python import cp_model

    import camplace.solver.engines.bitset.search as be

    rng = np.random.default_rng(9)
    dense = (rng.random((60, 12)) < 0.3).astype(float)
    w = rng.uniform(0.0, 1.0, 60)
    _forbid(monkeypatch, be, "_State")
    _forbid(monkeypatch, linear_solver_pb2, "MPModelProto")
    _forbid(monkeypatch, cp_model, "CpModel")
    best = brute_force_mode(dense, w, 3, "maxcover")
    for api in (solve, solve_maxcover):
        with memory_budget(_TINY):
            res = api(dense, w, 3)
        assert res.status == "feasible" and "memory_fallback" in str(res.stats)
        assert res.bound >= best * (1 - 1e-9) >= res.objective * (1 - 1e-9) - 1e-12
        for engine in ("exact", "mip", "cpsat"):
            with memory_budget(_TINY), pytest.raises(CamplaceError) as ei:
                api(dense, w, 3, engine=engine)
            assert "\n" not in str(ei.value) and "GiB" in str(ei.value)


def test_conflicts_over_budget_fall_back_with_spacing(monkeypatch) -> None:
    rng = np.random.default_rng(10)
    dense = (rng.random((40, 30)) < 0.3).astype(float)
    w = rng.uniform(0.0, 1.0, 40)
    pos = rng.uniform(0.0, 10.0, size=(30, 3))
    _forbid(monkeypatch, modes, "conflict_pairs")
    res = solve(dense, w, 3, positions=pos, min_distance_m=4.0, memory_budget_bytes=_TINY)
    assert "memory_fallback" in res.stats and res.status == "feasible"
    sel = res.selected
    assert all(np.linalg.norm(pos[a] - pos[b]) >= 4.0 for a, b in itertools.combinations(sel, 2))
    best = brute_force_mode(dense, w, 3, "maxcover", pos=pos, dmin=4.0)
    assert res.bound >= best * (1 - 1e-9) >= res.objective * (1 - 1e-9) - 1e-12
    for kw in (dict(engine="mip"), dict(mode="setcover", k=None)):
        k = kw.pop("k", 3)
        with pytest.raises(CamplaceError) as ei:
            solve(dense, w, k, positions=pos, min_distance_m=4.0, memory_budget_bytes=_TINY, **kw)
        assert "\n" not in str(ei.value) and "min_distance_m" in str(ei.value)


def test_setcover_over_budget_stops() -> None:
    dense = np.eye(6)
    with pytest.raises(CamplaceError) as ei:
        solve(dense, np.ones(6), mode="setcover", memory_budget_bytes=_TINY)
    assert "\n" not in str(ei.value) and "GiB" in str(ei.value)


def test_angle_engine_sizes_its_frontier_to_the_budget(medium) -> None:
    """Under a tight budget the engine still runs, with fewer open tuples allowed."""
    dense, w, pos, pts, best = medium
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, engine="exact",
                memory_budget_bytes=40 << 20)
    es = res.stats["engine_stats"]
    assert ae._FRONTIER_MIN <= es["open_tuples_max"] < ae._FRONTIER_MAX
    assert es["memory_estimate_bytes"] <= 40 << 20
    assert res.status == "optimal" and res.objective == pytest.approx(best, rel=1e-9)


# ---- bounds: the count first, angle-free tuples, cone refinement only where it prunes ----------


def _far_instance(m: int, n: int, seed: int):
    """Points on a unit sphere, cameras 20..60 units away (small parallax: many tuples angle-free)."""
    dense, w, pos, pts = _sphere_instance(m, n, seed)
    pos = pos / np.linalg.norm(pos, axis=1, keepdims=True) * np.random.default_rng(seed).uniform(20, 60, (n, 1))
    ray = pos[None, :, :] - pts[:, None, :]
    dense = (np.einsum("id,ijd->ij", pts, ray) > 0).astype(float)
    return dense, w, pos, pts


def _angles_deg(pos: np.ndarray, pts: np.ndarray, a: int, b: int) -> np.ndarray:
    """(m,) angle at every point between the rays to cameras a and b (arctan2, as the oracle)."""
    u, v = pos[a] - pts, pos[b] - pts
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("id,id->i", u, v)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_angle_free_tuples_make_the_angle_at_every_point(seed) -> None:
    """A tuple of single cameras called angle-free has every pair making the angle at every point
    (checked with arctan2 at every point); and such tuples exist here (the test can fail)."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(300, 3))
    n = 24
    pos = rng.normal(size=(n, 3))
    pos = pos / np.linalg.norm(pos, axis=1, keepdims=True) * rng.uniform(0.5, 30.0, (n, 1))  # some inside
    dirs, par = ae._sphere_directions(pts, pos)
    lo = np.arange(n, dtype=np.int64)
    hi = lo + 1
    theta = 25.0
    found = 0
    for tup in itertools.combinations(range(n), 3):
        nodes = np.asarray(tup, dtype=np.int64)
        if not ae.AK.angle_free(nodes, 3, lo, hi, dirs, par, 0, np.radians(theta)):
            continue
        found += 1
        for a, b in itertools.combinations(tup, 2):
            assert _angles_deg(pos, pts, a, b).min() >= theta
    assert found > 0
    # a camera inside the points' sphere is never part of an angle-free pair
    inside = np.flatnonzero(np.linalg.norm(pos - 0.5 * (pts.min(0) + pts.max(0)), axis=1)
                            <= np.linalg.norm(pts - 0.5 * (pts.min(0) + pts.max(0)), axis=1).max())
    assert inside.size > 0
    for c in inside:
        others = [j for j in range(n) if j != c][:2]
        nodes = np.sort(np.asarray([c, *others], dtype=np.int64))
        assert not ae.AK.angle_free(nodes, 3, lo, hi, dirs, par, 0, np.radians(theta))


@pytest.mark.parametrize(("seed", "fixed", "views"), [(0, (), 2), (1, (), 2), (2, (4,), 2), (3, (), 3)])
def test_angle_engine_far_cameras_equals_enumeration(seed, fixed, views) -> None:
    """Far cameras: most tuples are angle-free (their count bound is their angle bound, and for
    single cameras their exact value), also with a fixed camera and with three views."""
    dense, w, pos, pts = _far_instance(260, 15, seed)
    k = 3 - len(fixed)
    best, _ = _enumerate(dense, w, pos, pts, k, views, 30.0, fixed)
    res = solve(dense, w, k, mode="multiview", views=views, min_angle_deg=30.0, positions=pos, points=pts,
                fixed=fixed, engine="exact")
    assert res.status == "optimal" and res.objective == pytest.approx(best, rel=1e-9)
    assert set(fixed) <= set(res.selected)
    assert _value(dense, w, pos, pts, res.selected, views, 30.0) == pytest.approx(best, rel=1e-9)
    assert res.stats["engine_stats"]["angle_free"] > 0


@pytest.mark.parametrize("sample", [3, 10**9])
@pytest.mark.parametrize("seed", [0, 2, 3])
def test_angle_engine_without_cone_refinement_equals_enumeration(monkeypatch, seed, sample) -> None:
    """With the cone refinement switched off for every tuple of clusters after the root (tried on
    one child in ``sample`` only), bounds stay valid: the optimum is still proven."""
    dense, w, pos, pts = _sphere_instance(300, 16, seed, spread=1.0 if seed < 2 else 0.03)
    angle = (20.0, 35.0, 12.5, 50.0)[seed]
    best, _ = _enumerate(dense, w, pos, pts, 3, 2, angle)
    monkeypatch.setattr(ae._Tree, "_learn", lambda self, refined, cut: self.refine.fill(False))
    monkeypatch.setattr(ae, "_REFINE_SAMPLE", sample)
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=angle, positions=pos, points=pts,
                engine="exact")
    assert res.status == "optimal" and res.objective == pytest.approx(best, rel=1e-9)
    assert _value(dense, w, pos, pts, res.selected, 2, angle) == pytest.approx(best, rel=1e-9)


@pytest.mark.parametrize("checks", [1, 3, 6])
def test_angle_engine_interrupted_without_refinement_keeps_a_valid_bound(monkeypatch, medium, checks) -> None:
    dense, w, pos, pts, best = medium
    solve_deadline(monkeypatch, ExpiringDeadline(checks))  # the solve's one deadline
    monkeypatch.setattr(ae, "_BATCH", 4)
    monkeypatch.setattr(ae, "_CHUNK", 2)
    monkeypatch.setattr(ae._Tree, "_learn", lambda self, refined, cut: self.refine.fill(False))
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, engine="exact")
    v = _value(dense, w, pos, pts, res.selected, 2, 20.0)
    assert res.objective == pytest.approx(v, rel=1e-9)
    assert res.bound >= best * (1 - 1e-9) and best >= v * (1 - 1e-9)


def test_refinement_levels_follow_the_margin_they_remove() -> None:
    """A level stays refined while its tries remove at least the share of their margins over the
    incumbent on average (a prune removes all of it), and goes off below it: level 2 prunes few
    tuples but trims the others a lot (the angle binds), level 5 prunes as many and trims the
    others hardly at all, level 7 prunes none and trims half."""
    t = ae._Tree.__new__(ae._Tree)
    t.refine = np.ones(64, dtype=np.bool_)
    t.tries = np.zeros(64, dtype=np.int64)
    t.wins = np.zeros(64, dtype=np.int64)
    t.cuts = np.zeros(64)
    n = ae._REFINE_TRIALS
    pruned = n // 10
    codes = np.concatenate([np.full(pruned, -3), np.full(n - pruned, 3), np.full(pruned, -6), np.full(n - pruned, 6),
                            np.full(n, 8)])
    cut = np.concatenate([np.ones(pruned), np.full(n - pruned, 0.4), np.ones(pruned), np.full(n - pruned, 0.02),
                          np.full(n, 0.5)])
    t._learn(codes.astype(np.int8).reshape(1, -1), cut.reshape(1, -1))
    assert t.refine[2] and not t.refine[5] and t.refine[7] and t.refine[0] and t.refine[9]
    assert t.tries[2] == n and t.wins[2] == pruned and t.tries[5] == n and t.wins[5] == pruned and t.wins[7] == 0
    assert t.cuts[2] == pytest.approx(pruned + 0.4 * (n - pruned))


def test_lazy_refinement_requeues_and_still_equals_enumeration(monkeypatch) -> None:
    """With batches of a few tuples, a tuple the refinement pushes below the best open bound goes
    back to the open set unsplit (``requeued``); the optimum is still the enumerated one."""
    monkeypatch.setattr(ae, "_BATCH", 4)
    monkeypatch.setattr(ae, "_BATCH_MIN", 1)
    monkeypatch.setattr(ae, "_CHUNK", 1)
    requeued = 0
    for seed in (3, 4, 5):
        dense, w, pos, pts = _sphere_instance(300, 20 if seed > 3 else 16, seed, spread=0.03)
        angle = 50.0 if seed == 3 else 60.0
        best, _ = _enumerate(dense, w, pos, pts, 3, 2, angle)
        res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=angle, positions=pos, points=pts,
                    engine="exact")
        assert res.status == "optimal" and res.objective == pytest.approx(best, rel=1e-9)
        assert _value(dense, w, pos, pts, res.selected, 2, angle) == pytest.approx(best, rel=1e-9)
        requeued += res.stats["engine_stats"]["requeued"]
    assert requeued > 0


@pytest.mark.parametrize("pw", [0, 3, 7])
@pytest.mark.parametrize("seed", [0, 1])
def test_three_node_counter_equals_numpy(pw, seed) -> None:
    """The block-summed counter for three distinct nodes (two views, integer weights) against a
    numpy count: a row, or a pair of rows (first rows in words [0, pw), their partners pw words
    later, the pair's weight on the first), is missed when fewer than two nodes observe it; with
    an early stop the result reaches ``need`` exactly when the full count does."""
    rng = np.random.default_rng(seed)
    n_words, n_nodes = 2 * pw + 9, 5
    bits = rng.random((n_nodes, n_words * 64)) < 0.45
    weights = rng.integers(0, 6, n_words * 64).astype(np.float64)
    weights[pw * 64 : 2 * pw * 64] = 0.0  # partners carry no weight of their own
    weights[-23:] = 0.0  # padding rows
    levels = np.packbits(bits.reshape(n_nodes, n_words, 64), axis=2, bitorder="little").view(np.uint64)
    levels = np.ascontiguousarray(levels.reshape(1, n_nodes, n_words))
    from camplace.solver._support import bitkernels as BK
    from camplace.solver.engines.angle import _kernels as AK

    planes = BK.weight_planes(weights)
    for a, b, c in [(0, 1, 2), (1, 3, 4), (0, 2, 4)]:
        two = bits[a].astype(int) + bits[b] + bits[c] >= 2
        hit = two.copy()
        hit[: pw * 64] |= two[pw * 64 : 2 * pw * 64]
        full = float(weights[~hit].sum())
        assert BK.shortfall2_three(levels, a, b, c, planes, np.inf, pw) == full
        for need in (0.25 * full, 0.9 * full, full, full + 1):
            got = BK.shortfall2_three(levels, a, b, c, planes, need, pw)
            assert (got >= need) == (full >= need) and got <= full


@pytest.mark.parametrize("seed", [0, 1])
def test_grouped_two_view_counter_with_a_repeated_node_equals_numpy(seed) -> None:
    """k = 4 with one node twice (three groups): the node's rows seen by two of its columns
    (``levels[1]``) count, so the three-distinct-nodes counter must not be taken."""
    from camplace.solver._support import bitkernels as BK

    rng = np.random.default_rng(seed)
    n_words, n_nodes = 6, 4
    l0 = rng.random((n_nodes, n_words * 64)) < 0.4
    l1 = l0 & (rng.random((n_nodes, n_words * 64)) < 0.5)  # seen by two columns of the node
    weights = rng.integers(0, 4, n_words * 64).astype(np.float64)
    bits = np.stack([l0, l1])
    levels = np.ascontiguousarray(np.packbits(bits.reshape(2, n_nodes, n_words, 64), axis=3, bitorder="little")
                                  .view(np.uint64).reshape(2, n_nodes, n_words))
    planes = BK.weight_planes(weights)
    nodes = np.array([0, 0, 1, 3], dtype=np.int64)
    views = l0[0].astype(int) + l1[0] + l0[1] + l0[3]
    full = float(weights[views < 2].sum())
    scratch = np.zeros(4, dtype=np.int64)
    got = BK.shortfall2_grouped(levels, nodes, 4, weights, planes, np.uint64(0xFFFFFFFFFFFFFFFF), np.inf, 0,
                                scratch, scratch.copy())
    assert got == full



# ---- ball refinement (issue 30): rows tested one by one against balls around a node's cameras ---


def _aims_instance(m: int, n_pos: int, seed: int, aims: int = 3):
    """comet-flyby's structure in small: ``aims`` poses at every position (they never make an
    angle with each other), positions along a path past a unit sphere of points; a pose observes
    the facing points within 50 degrees of its aim (towards the centre, turned by up to 35 degrees)."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(m, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    path = np.stack([np.linspace(-4.0, 4.0, n_pos), np.full(n_pos, 2.5), rng.uniform(-0.5, 0.5, n_pos)], axis=1)
    path += rng.normal(scale=0.2, size=path.shape)
    pos = np.repeat(path, aims, axis=0)
    aim = -pos / np.linalg.norm(pos, axis=1, keepdims=True) + rng.uniform(-0.6, 0.6, size=pos.shape)
    aim /= np.linalg.norm(aim, axis=1, keepdims=True)
    ray = pts[:, None, :] - pos[None, :, :]  # camera -> point
    dist = np.linalg.norm(ray, axis=2)
    facing = np.einsum("id,ijd->ij", pts, -ray) > 0
    seen = facing & (np.einsum("jd,ijd->ij", aim, ray) / dist >= np.cos(np.radians(50.0)))
    w = rng.integers(1, 4, size=m).astype(float) if seed % 2 else rng.uniform(0.1, 1.0, size=m)
    return seen.astype(float), w, pos, pts


def _captured_tree(monkeypatch, dense, w, pos, pts, fixed=()):
    """Run the angle engine briefly (plain layout) and return its ``_Tree`` and the search rows."""
    got = {}

    class Keep(ae._Tree):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            got["tree"] = self

    monkeypatch.setattr(ae, "_Tree", Keep)
    monkeypatch.setattr(ae, "_PAIRS_MIN_SHARE", 2.0)  # the plain layout: a bit row is a matrix row
    n = dense.shape[1]
    fixed = np.asarray(fixed, dtype=np.int64)
    free = np.setdiff1d(np.arange(n), fixed)
    ae.solve_angle(sp.csr_matrix(dense), w, 3, 2, 20.0, pos, pts, fixed, free, deadline=Deadline(None),
                   budget_bytes=1 << 30)
    return got["tree"]


def _tuple_bound(tree, nodes, balls: bool) -> float:
    from camplace.solver.engines.angle import _kernels as AK

    possible, always, self_ok = tree.tables
    k = len(nodes)
    sf = AK.angle_shortfall(tree.levels, tree.cones, np.asarray(nodes, dtype=np.int64), k, 2, tree.lo, tree.campos,
                            tree.fbits, tree.fcones, tree.fpos, tree.fpair, tree.lw, tree.planes, tree.mask, np.inf,
                            np.zeros(3, dtype=np.uint64), np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64),
                            tree.pw, False, tree.pts, possible, always, self_ok, 20.0, tree.cos_t,
                            tree.balls if balls else np.zeros((0, 4)), tree.blocks[0], tree.blocks[1])
    return tree.total - sf


@pytest.mark.parametrize("seed,fixed", [(0, ()), (1, ()), (2, (4,)), (3, ())])
def test_ball_refinement_bounds_every_choice_of_a_node_tuple(monkeypatch, seed, fixed) -> None:
    """For every tuple of three tree nodes, the refined bound (cones, then rows against the
    nodes' balls) is at least the enumerated value of every choice of three distinct cameras,
    one per node (on the engine's rows, fixed cameras added); it is never above the bound from
    the cones alone and below it on some tuples (the balls do something)."""
    dense, w, pos, pts = _aims_instance(220, 5, seed)
    tree = _captured_tree(monkeypatch, dense, w, pos, pts, fixed)
    good = _pair_ok(dense, pos, pts, 20.0)
    obs = dense > 0
    lw = tree.lw
    # the bit rows' matrix rows (plain layout): each bit row's point is a matrix row's (points are distinct)
    where = {tuple(p): i for i, p in enumerate(pts)}
    brow = np.array([where.get(tuple(tree.pts[b]), -1) if lw[b] > 0 else -1 for b in range(lw.size)])
    assert (brow[lw > 0] >= 0).all()
    n_nodes = tree.lo.shape[0]
    obs_b, good_b = obs[brow], good[brow]  # the bit rows' observations and pairs, once
    tighter = 0
    for nodes in itertools.combinations_with_replacement(range(n_nodes), 3):
        members = [tree.cols_ord[tree.lo[v]:tree.hi[v]] for v in nodes]
        best = -np.inf
        for choice in itertools.product(*members):
            if len(set(choice)) < 3:
                continue
            cols = list(choice) + list(fixed)
            ok = (obs_b[:, cols].sum(axis=1) >= 2) & good_b[:, cols][:, :, cols].any(axis=(1, 2))
            best = max(best, float(lw[ok & (lw > 0)].sum()))
        if best == -np.inf:
            continue
        with_balls, cones_only = _tuple_bound(tree, nodes, True), _tuple_bound(tree, nodes, False)
        tol = 1e-9 * max(1.0, float(lw.sum()))
        assert with_balls >= best - tol, (nodes, with_balls, best)
        assert with_balls <= cones_only + tol
        tighter += with_balls < cones_only - tol
    assert tighter > 0


@pytest.mark.parametrize("seed,scale", [(0, 64), (1, 1024), (2, 40_000), (3, 0)])
def test_bisection_order_with_positions_equals_thermometer_codes(seed, scale) -> None:
    """The angle engine's column order (bitsets plus the positions' grid levels, as an L1 term of
    the distance) is the order of the plain bisection on the bitsets with the levels appended as
    thermometer codes (runs of ones), made explicitly; ties (equal columns, poses of one
    position) included."""
    from camplace.solver._support import bitkernels as BK

    dense, _, pos, _ = _aims_instance(150, 12, seed)
    dense[:, 5] = dense[:, 6]  # two equal columns
    q = sp.csr_matrix(dense)
    bits = BK.build_bits(q.indptr, q.indices, q.data, np.arange(dense.shape[0], dtype=np.int64),
                         np.arange(dense.shape[1], dtype=np.int64), dense.shape[1])
    lo = pos.min(axis=0)
    lev = np.floor((pos - lo) * (scale / float((pos.max(axis=0) - lo).max()))).astype(np.int64)
    n_axis = (int(lev.max()) + 64) // 64
    therm = np.arange(64 * n_axis)[None, :]
    codes = [np.packbits(therm < lev[:, d : d + 1], axis=1, bitorder="little").view(np.uint64) for d in range(3)]
    want = BK.bisection_order(np.ascontiguousarray(np.concatenate([bits, *codes], axis=1)))
    got = BK.bisection_order_with(bits, np.ascontiguousarray(lev))
    assert got.tolist() == want.tolist()
    assert sorted(got.tolist()) == list(range(dense.shape[1]))
    if scale == 0:
        assert got.tolist() == BK.bisection_order(bits).tolist()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_angle_engine_with_poses_at_one_position_equals_enumeration(seed) -> None:
    """Three poses per position along a path (the comet-flyby structure the balls are for)."""
    dense, w, pos, pts = _aims_instance(260, 6, seed)
    fixed = (3,) if seed == 2 else ()
    k = 2 if fixed else 3
    best, _ = _enumerate(dense, w, pos, pts, k, 2, 20.0, fixed)
    res = solve(sp.csr_matrix(dense), w, k, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts,
                fixed=fixed, engine="exact")
    assert res.status == "optimal" and res.objective == pytest.approx(best, rel=1e-9)
    assert _value(dense, w, pos, pts, res.selected, 2, 20.0) == pytest.approx(best, rel=1e-9)


@pytest.mark.parametrize("checks", [0, 1, 2, 4, 7])
def test_angle_engine_with_poses_at_one_position_interrupted_keeps_a_valid_bound(monkeypatch, checks) -> None:
    dense, w, pos, pts = _aims_instance(300, 8, 5)
    best, _ = _enumerate(dense, w, pos, pts, 3, 2, 20.0)
    solve_deadline(monkeypatch, ExpiringDeadline(checks))
    monkeypatch.setattr(ae, "_BATCH", 4)
    monkeypatch.setattr(ae, "_BATCH_MIN", 1)
    monkeypatch.setattr(ae, "_CHUNK", 2)
    res = solve(dense, w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, engine="exact")
    v = _value(dense, w, pos, pts, res.selected, 2, 20.0)
    assert res.objective == pytest.approx(v, rel=1e-9)
    assert res.bound >= best * (1 - 1e-9) and best >= v * (1 - 1e-9)
    if res.status == "optimal":
        assert v == pytest.approx(best, rel=1e-9)


# ---- the incumbent's large-neighbourhood search ---------------------------------------------------


@pytest.mark.parametrize("seed,views,n_fixed", [(0, 2, 0), (1, 2, 1), (2, 3, 0), (3, 3, 2)])
def test_set_values_equal_the_oracle(seed, views, n_fixed) -> None:
    """Every set's value from the column lists equals the arctan2 oracle (fixed cameras appended)."""
    from camplace.solver.engines.angle import _kernels as AK

    dense, w, pos, pts = _aims_instance(240, 10, seed)
    q = sp.csr_matrix(dense)
    rng = np.random.default_rng(seed)
    n = dense.shape[1]
    w = np.where(rng.random(w.size) < 0.2, 0.0, w)  # rows of weight 0 are left out of the lists
    search = np.flatnonzero(w > 0)
    row_id = np.full(w.size, -1, dtype=np.int64)
    row_id[search] = np.arange(search.size)
    cols = np.sort(rng.choice(n, size=20, replace=False))
    local = np.full(n, -1, dtype=np.int64)
    local[cols] = np.arange(cols.size)
    ptr, rows = AK.column_lists(q.indptr, q.indices, q.data, row_id, local, cols.size)
    for c in range(cols.size):  # the lists are the columns' rows of weight > 0, numbered among those
        assert search[rows[ptr[c]:ptr[c + 1]]].tolist() == np.flatnonzero((dense[:, cols[c]] > 0) & (w > 0)).tolist()
    fixed = list(range(n_fixed))
    sets = np.array([rng.choice(np.arange(n_fixed, cols.size), size=3, replace=False) for _ in range(40)])
    full = np.concatenate([sets, np.tile(fixed, (sets.shape[0], 1))], axis=1).astype(np.int64)
    got = AK.set_values(ptr, rows, full, w[search], np.ascontiguousarray(pos[cols]), np.ascontiguousarray(pts[search]),
                        views, 20.0, 3)
    good = _pair_ok(dense, pos, pts, 20.0)  # the oracle's pairs, once for the 40 sets
    want = [_value(dense, w, pos, pts, cols[s], views, 20.0, good) for s in full]
    assert got == pytest.approx(want, rel=1e-12, abs=1e-12)
    assert max(want) > 0


def _climbed(dense, w, pos, pts, start, views, fixed=(), forbidden=(), layout="csr"):
    from camplace.visibility.bits import bits_from_csr

    n = dense.shape[1]
    fixed = np.asarray(fixed, dtype=np.int64)
    free = np.setdiff1d(np.arange(n), np.concatenate([fixed, np.asarray(forbidden, dtype=np.int64)]))
    q = sp.csr_matrix(dense) if layout == "csr" else bits_from_csr(sp.csr_matrix(dense > 0))
    inc = ae._Incumbent(ae._Rows(q), w, pos, pts, views, 20.0, fixed, free, 0.0, Deadline(None))
    inc.climb(start, Deadline(None))
    return inc, free


@pytest.mark.parametrize("layout", ["csr", "bits"])
@pytest.mark.parametrize("seed,views,fixed", [(0, 2, ()), (1, 2, (7,)), (2, 3, ()), (4, 2, ())])
def test_climb_ends_at_a_local_optimum_of_its_moves(monkeypatch, seed, views, fixed, layout) -> None:
    """From a random start the climb returns a feasible set whose value is its exact value, at
    least the start's, and no set of its final neighbourhood (one or two cameras replaced by
    columns of their move lists, each valued by the oracle) is better."""
    monkeypatch.setattr(ae, "_LNS_NEAR", 6)
    monkeypatch.setattr(ae, "_LNS_FAR", 2)
    dense, w, pos, pts = _aims_instance(200, 14, seed)
    rng = np.random.default_rng(seed)
    forbidden = (5,)
    n = dense.shape[1]
    pool = np.setdiff1d(np.arange(n), np.array(fixed + forbidden, dtype=np.int64))
    start = sorted(int(c) for c in rng.choice(pool, size=3, replace=False))
    inc, free = _climbed(dense, w, pos, pts, start, views, fixed, forbidden, layout)
    sel = list(inc.best_set)
    assert len(sel) == len(set(sel)) == 3 and set(sel) <= set(free.tolist())
    value = _value(dense, w, pos, pts, list(fixed) + sel, views, 20.0)
    assert inc.best == pytest.approx(value, rel=1e-12)
    assert value >= _value(dense, w, pos, pts, list(fixed) + start, views, 20.0) - 1e-12
    near = [inc._near(c, free, pos[free], ae._move_list_size(3)) for c in sel]
    # itself, the 5 others of the 6 nearest, every 2nd of the next 12
    assert all(x[0] == c and x.size == len(set(x.tolist())) == 12 for x, c in zip(near, sel, strict=True))
    good = _pair_ok(dense, pos, pts, 20.0)  # the oracle's pairs, once for the whole neighbourhood
    for p, qq in itertools.combinations(range(3), 2):
        for a in near[p]:
            for b in near[qq]:
                s = list(sel)
                s[p], s[qq] = int(a), int(b)
                if len(set(s)) == 3:
                    assert _value(dense, w, pos, pts, list(fixed) + s, views, 20.0, good) <= value + 1e-12


@pytest.mark.parametrize("seed,views", [(0, 2), (3, 2), (5, 3)])
def test_climb_pairs_only_the_best_single_moves(monkeypatch, seed, views) -> None:
    """With pairs of moves taken among each list's 3 best single moves, the climb still ends
    where no single move of its full lists is better (each valued by the oracle), nor any pair
    of moves both strictly among the 3 best single moves of their lists (ties at the cut may
    fall either way); its value is the oracle's and at least the start's."""
    monkeypatch.setattr(ae, "_LNS_NEAR", 6)
    monkeypatch.setattr(ae, "_LNS_FAR", 2)
    monkeypatch.setattr(ae, "_LNS_TOP", 3)
    assert ae._top_size(3) == 3
    dense, w, pos, pts = _aims_instance(200, 14, seed)
    rng = np.random.default_rng(seed)
    n = dense.shape[1]
    start = sorted(int(c) for c in rng.choice(n, size=3, replace=False))
    inc, free = _climbed(dense, w, pos, pts, start, views)
    sel = list(inc.best_set)
    value = _value(dense, w, pos, pts, sel, views, 20.0)
    assert inc.best == pytest.approx(value, rel=1e-12)
    assert value >= _value(dense, w, pos, pts, start, views, 20.0) - 1e-12
    near = [inc._near(c, free, pos[free], ae._move_list_size(3)) for c in sel]
    good = _pair_ok(dense, pos, pts, 20.0)
    strict = []  # each list's moves strictly among its 3 best single moves (by the oracle)
    for p in range(3):
        one = {}
        for a in near[p]:
            s = list(sel)
            s[p] = int(a)
            if len(set(s)) == 3:
                one[int(a)] = _value(dense, w, pos, pts, s, views, 20.0, good)
                assert one[int(a)] <= value + 1e-12  # no single move of the whole list is better
        vals = sorted(one.values(), reverse=True)
        cut = vals[2] if len(vals) > 2 else -np.inf
        strict.append([a for a, v in one.items() if v > cut + 1e-12])
    assert sum(len(x) for x in strict) > 0
    for p, qq in itertools.combinations(range(3), 2):
        for a in strict[p]:
            for b in strict[qq]:
                s = list(sel)
                s[p], s[qq] = a, b
                if len(set(s)) == 3:
                    assert _value(dense, w, pos, pts, s, views, 20.0, good) <= value + 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_middle_rung_returns_its_climbed_start_valued_exactly(seed) -> None:
    """A middle rung (``rung=True`` with a ``start`` and a time limit) climbs and swaps from its
    start and returns without a search: feasible, every countable row as the bound, an answer at
    least the start's, and every value it reports (start, start climbed, the incumbent) the
    arctan2 enumeration's of the sets they name."""
    dense, w, pos, pts = _aims_instance(200, 14, seed)
    q = sp.csr_matrix(dense)
    n = dense.shape[1]
    rng = np.random.default_rng(seed)
    start = sorted(int(c) for c in rng.choice(n, size=3, replace=False))
    out = ae.solve_angle(q, w, 3, 2, 20.0, pos, pts, np.zeros(0, dtype=np.int64), np.arange(n),
                         deadline=Deadline(30.0), budget_bytes=memory_budget_bytes(), start=start, rung=True)
    st_ = out.stats
    assert out.status == "feasible" and st_["skipped"] == "search" and st_["bound_evaluations"] == 0
    good = _pair_ok(dense, pos, pts, 20.0)
    value = _value(dense, w, pos, pts, list(out.selected), 2, 20.0, good)
    assert st_["start"] == pytest.approx(_value(dense, w, pos, pts, start, 2, 20.0, good), rel=1e-12)
    assert st_["initial_incumbent"] == pytest.approx(value, rel=1e-12)
    assert st_["start"] - 1e-12 <= st_["start_climbed"] <= value + 1e-12
    best, _ = _enumerate(dense, w, pos, pts, 3, 2, 20.0)
    assert value <= best + 1e-12 and out.bound >= best - 1e-12
    # the same call without ``rung`` searches, and proves the enumerated optimum
    full = ae.solve_angle(q, w, 3, 2, 20.0, pos, pts, np.zeros(0, dtype=np.int64), np.arange(n),
                          deadline=Deadline(30.0), budget_bytes=memory_budget_bytes(), start=start)
    assert full.status == "optimal" and full.bound == pytest.approx(best, rel=1e-12)


def test_climb_improves_a_poor_start() -> None:
    """The climb moves: from the worst enumerated set of a small instance it reaches a better one."""
    dense, w, pos, pts = _aims_instance(200, 8, 6)
    best, vals = _enumerate(dense, w, pos, pts, 3, 2, 20.0)
    worst = list(itertools.combinations(range(dense.shape[1]), 3))[int(np.argmin(vals))]
    inc, _ = _climbed(dense, w, pos, pts, list(worst), 2)
    assert inc.best > float(vals.min()) + 1e-9
    assert inc.best <= best + 1e-9


@pytest.mark.parametrize("seed,theta_deg", [(0, 20.0), (1, 20.0), (2, 5.0), (3, 60.0), (4, 120.0), (5, 170.0)])
def test_ball_row_test_keeps_every_row_a_pair_of_cameras_in_the_balls_may_use(seed, theta_deg) -> None:
    """The row test of the ball refinement (arcs from each row's distance by the tangent lengths,
    64 rows at once, a block shortcut) against arcsin and arccos in numpy: every row where cameras
    drawn inside the two balls make the angle is kept, every row whose directions to the two
    centres are clearly closer than the angle less both arcs ``asin(radius / distance)`` from that
    row's point is dropped, and the others are kept; blocks wide enough to meet the balls
    included (the old test took the arcs from the block's sphere and kept all of those)."""
    from camplace.solver.engines.angle import _kernels as AK

    rng = np.random.default_rng(seed)
    theta = np.radians(theta_deg)
    trig = AK.ball_angle_table(theta)
    kept = dropped = 0
    for _ in range(80):
        centre = rng.normal(size=3)
        pts = np.ascontiguousarray(centre + rng.normal(scale=rng.uniform(0.05, 4.0), size=(64, 3)))
        bc = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        brad = np.linalg.norm(pts - bc, axis=1).max() * (1 + 1e-9) + 1e-12
        centers, radius = bc[None, :], np.array([brad])
        balls = []
        for _ in range(2):
            c = bc + rng.normal(size=3) * rng.uniform(2.0, 12.0)
            rho = 0.0 if rng.random() < 0.25 else rng.uniform(0.01, 2.0)
            balls.append((c, rho))
        x = np.uint64(rng.integers(0, 2**63, dtype=np.int64)) | np.uint64(1 << 63) if rng.random() < 0.5 else ~np.uint64(0)
        got = int(AK._ball_bits(x, 0, *balls[0][0], balls[0][1], *balls[1][0], balls[1][1], pts, trig, centers, radius))
        rows = [t for t in range(64) if int(x) >> t & 1]
        assert got & ~int(x) == 0
        # cameras inside the balls: every row where some drawn pair makes the angle is kept
        cams = [c + rho * rng.uniform(-1, 1, size=(40, 3)) / np.sqrt(3) for c, rho in balls]
        for t in rows:
            u = cams[0] - pts[t]
            v = cams[1] - pts[t]
            cosang = np.einsum("id,jd->ij", u, v) / np.outer(np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1))
            if (np.degrees(np.arccos(np.clip(cosang, -1, 1))) >= theta_deg).any():
                assert got >> t & 1, (t, theta_deg)
        # the arc formula from each row's point: rows clearly closer than the angle less both arcs
        # are dropped, the others kept (a point inside a ball: kept)
        for t in rows:
            u = balls[0][0] - pts[t]
            v = balls[1][0] - pts[t]
            du, dv = np.linalg.norm(u), np.linalg.norm(v)
            if du <= balls[0][1] or dv <= balls[1][1]:
                assert got >> t & 1
                continue
            lim = theta - np.arcsin(balls[0][1] / du) - np.arcsin(balls[1][1] / dv)
            ang = np.arccos(np.clip(u @ v / (du * dv), -1, 1))
            if ang >= lim - 1e-7:
                assert got >> t & 1, (t, ang, lim)
                kept += 1
            elif ang < lim - 1e-5:
                assert not got >> t & 1, (t, ang, lim)
                dropped += 1
    assert kept > 0 and (dropped > 0 or theta_deg < 10)


@pytest.mark.parametrize("seed,theta_deg", [(0, 20.0), (1, 5.0), (2, 90.0)])
def test_self_row_test_keeps_every_row_two_cameras_of_a_ball_may_use(seed, theta_deg) -> None:
    """The repeated node's row test against numpy: rows where two cameras drawn in the ball make the
    angle are kept; rows where the ball's diameter subtends clearly less than the angle
    (``2 asin(radius / distance)``) are dropped."""
    from camplace.solver.engines.angle import _kernels as AK

    rng = np.random.default_rng(seed)
    trig = AK.ball_angle_table(np.radians(theta_deg))
    kept = dropped = 0
    for _ in range(40):
        pts = np.ascontiguousarray(rng.normal(scale=rng.uniform(0.5, 5.0), size=(64, 3)))
        c = rng.normal(size=3) * rng.uniform(2.0, 12.0)
        rho = rng.uniform(0.1, 3.0)
        x = ~np.uint64(0)
        got = int(AK._self_bits(x, 0, c[0], c[1], c[2], rho, pts, trig))
        cams = c + rho * rng.normal(size=(60, 3)) / np.sqrt(3) * 0.57
        cams = c + (cams - c) * np.minimum(1.0, rho / np.linalg.norm(cams - c, axis=1))[:, None]
        for t in range(64):
            u = cams - pts[t]
            u /= np.linalg.norm(u, axis=1)[:, None]
            if (np.degrees(np.arccos(np.clip(u @ u.T, -1, 1))) >= theta_deg).any():
                assert got >> t & 1
            d = np.linalg.norm(c - pts[t])
            if d <= rho:
                assert got >> t & 1
                continue
            span = 2 * np.arcsin(rho / d)
            if span >= np.radians(theta_deg) - 1e-7:
                assert got >> t & 1
                kept += 1
            elif span < np.radians(theta_deg) - 1e-5:
                assert not got >> t & 1
                dropped += 1
    assert kept > 0 and dropped > 0


def test_node_balls_hold_their_cameras_are_no_wider_than_the_box_centre_and_thread_independent() -> None:
    """Every node's ball holds all its cameras (numpy distances), its radius is at most the
    bounding box centre's (the steps keep the smallest radius met, the box centre first) and at
    least half the node's diameter, a single camera's ball is the camera (radius 0), and the balls
    are bit-identical at one and two threads."""
    import numba

    from camplace.solver._support import bitkernels as K
    from camplace.solver.engines.angle import _kernels as AK

    rng = np.random.default_rng(3)
    pos = np.ascontiguousarray(rng.normal(size=(200, 3)) * [30.0, 8.0, 6.0])
    bits = np.ascontiguousarray(rng.integers(0, 2**62, size=(200, 4)).astype(np.uint64))
    lo, hi, left, right, _ = K.build_tree(bits, 2)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = AK.node_balls(pos, lo, hi)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = AK.node_balls(pos, lo, hi)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(one, two)
    tighter = 0
    for v in range(lo.size):
        p = pos[lo[v]:hi[v]]
        d = np.linalg.norm(p - one[v, :3], axis=1)
        assert (d <= one[v, 3]).all()
        if p.shape[0] == 1:
            assert one[v, 3] == 0.0 and np.array_equal(one[v, :3], p[0])
            continue
        box = 0.5 * (p.min(axis=0) + p.max(axis=0))
        r_box = np.linalg.norm(p - box, axis=1).max()
        diam = max(np.linalg.norm(a - b) for a in p for b in p) if p.shape[0] <= 40 else 0.0
        assert one[v, 3] <= r_box * (1 + 1e-9) + 1e-12
        assert one[v, 3] >= 0.5 * diam * (1 - 1e-9)
        tighter += one[v, 3] < 0.99 * r_box
    assert tighter > 0
