"""Camera teams in modes quality and multiview (issue 31): the solver enforces them, against enumeration.

The oracle here enumerates every subset of the allowed columns itself, keeps the ones that meet
every constraint (``_ok`` of tests/solver/test_solver_team.py, which checks them without the
package) and scores them with numpy: ``sum_i w_i max_{j in S} q_ij`` (quality) and the weight of
the rows at least ``views`` chosen cameras observe, two of them with view rays at least
``min_angle_deg`` apart when given (multiview). The exact enumeration, SCIP and CP-SAT must reach
that optimum with every constraint met, or all say infeasible; the team constraints come alone
(counts, budget, zones) and combined (all of them with the pose limit, fixed and forbidden columns).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from camplace.solver.api import solve
from camplace.solver.options import SolveOptions
from camplace.solver.routes import choose_team_engine
from tests.solver.test_solver_team import _SETTINGS, _constraints, _ok, team_instances

#: Which constraint families an instance keeps: each alone, then all together.
_KEEP = {
    "counts": {"counts"},
    "budget": {"budget"},
    "zones": {"zones"},
    "combined": {"counts", "budget", "zones", "pose", "fixed"},
}


def _restrict(inst: dict, keep: set[str]) -> dict:
    """``inst`` with the constraint families outside ``keep`` dropped (so that one binds alone)."""
    out = dict(inst)
    if "counts" not in keep:
        out["model_limits"] = [(0, None)] * inst["n_models"]
    if "budget" not in keep:
        out["budget"] = None
    if "zones" not in keep:
        out["zones"] = np.zeros((inst["model"].size, 0), bool)
        out["zone_limits"] = []
    if "pose" not in keep:
        out["one_per_pose"] = False
    if "fixed" not in keep:
        out["fixed"], out["forbidden"] = (), ()
        n = inst["model"].size
        if out["cardinality"] == "exact" and out["k"] is not None:
            out["k"] = max(1, min(out["k"], n)) if n else 0
    return out


@st.composite
def graded_instances(draw, keep: str = "combined"):
    """A team instance (``team_instances``) with graded qualities in {0.25, 0.5, 0.75, 1} where a
    column observes a row, 1-5 denser rows added, camera positions per pose on an integer grid
    (metres) and points off it."""
    inst = _restrict(draw(team_instances()), _KEEP[keep])
    a = inst["a"]
    m, n = a.shape
    levels = np.array(draw(st.lists(st.sampled_from([0.25, 0.5, 0.75, 1.0]), min_size=m * n, max_size=m * n)),
                      dtype=np.float32).reshape(m, n)
    q = np.where(a > 0, levels, 0.0).astype(np.float32)
    # a few denser rows (4 in 5 entries observe), so that multiview rows reach 2-3 views often
    extra = draw(st.integers(1, 5))
    dense = np.array(draw(st.lists(st.sampled_from([0.0, 0.25, 0.5, 0.75, 1.0]), min_size=extra * n,
                                   max_size=extra * n)), dtype=np.float32).reshape(extra, n)
    q = np.concatenate([q, dense])
    w = np.concatenate([inst["w"], np.array(draw(st.lists(st.sampled_from([0.5, 1.0, 2.0]), min_size=extra,
                                                          max_size=extra)))])
    m = q.shape[0]
    n_poses = int(inst["pose"].max()) + 1 if n else 0
    grid = st.integers(-3, 3)
    pose_xyz = np.array(draw(st.lists(st.tuples(grid, grid, grid), min_size=n_poses, max_size=n_poses)),
                        dtype=np.float64).reshape(n_poses, 3)
    pts = np.array(draw(st.lists(st.tuples(grid, grid, grid), min_size=m, max_size=m)),
                   dtype=np.float64).reshape(m, 3) + 0.5  # never at a camera
    return {**inst, "a": q, "w": w, "pos": pose_xyz[inst["pose"]], "pts": pts}


def _score(inst: dict, sel: list[int], mode: str, views: int, min_angle: float | None) -> float:
    """The mode's objective of the full selection ``sel`` (numpy only; maxcover too)."""
    q, w = inst["a"].astype(np.float64), inst["w"]
    if not sel:
        return 0.0
    sub = q[:, sel]
    if mode == "quality":
        return float(w @ sub.max(axis=1))
    seen = sub > 0
    if mode == "maxcover":
        return float(w[seen.any(axis=1)].sum())
    ok = seen.sum(axis=1) >= views
    if min_angle is not None:
        paired = np.zeros(len(w), dtype=bool)
        for a, b in itertools.combinations(range(len(sel)), 2):
            ra = inst["pos"][sel[a]] - inst["pts"]
            rb = inst["pos"][sel[b]] - inst["pts"]
            cos = np.sum(ra * rb, axis=1) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
            paired |= seen[:, a] & seen[:, b] & (np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) >= min_angle)
        ok &= paired
    return float(w[ok].sum())


def _oracle(inst: dict, mode: str, views: int, min_angle: float | None) -> float | None:
    """The best objective over every feasible team (None: none is feasible)."""
    n = inst["model"].size
    fixed = list(inst["fixed"])
    free = [j for j in range(n) if j not in inst["fixed"] and j not in inst["forbidden"]]
    best = None
    for r in range(len(free) + 1):
        for combo in itertools.combinations(free, r):
            sel = fixed + list(combo)
            if _ok(sel, inst["fixed"], inst):
                v = _score(inst, sel, mode, views, min_angle)
                best = v if best is None or v > best else best
    return best


def _check(inst: dict, mode: str, engine: str, views: int = 2, min_angle: float | None = None):
    """Solve with ``engine`` and compare with the oracle; returns the result (None: case skipped)."""
    if inst["k"] is None and inst["cardinality"] == "exact":
        return None  # k is required without a budget cardinality (a one-line error, as for maxcover)
    want = _oracle(inst, mode, views, min_angle)
    extra = {}
    if mode == "multiview":
        extra = dict(views=views, min_angle_deg=min_angle)
    opts = SolveOptions(mode=mode, k=inst["k"], engine=engine, fixed=inst["fixed"], forbidden=inst["forbidden"],
                        team=_constraints(inst), **extra)
    res = solve(sp.csr_matrix(inst["a"]), inst["w"], positions=inst["pos"] if min_angle is not None else None,
                points=inst["pts"] if min_angle is not None else None, options=opts)
    assert res.stats["engine_choice"]["route"] == "team"
    if want is None:
        assert res.status == "infeasible", (res, inst)
        assert res.selected == () and math.isnan(res.objective) and math.isinf(res.gap)
        return res
    assert res.status == "optimal", (res, want, inst)
    assert _ok(res.selected, inst["fixed"], inst), (res.selected, inst)
    assert _constraints(inst).violations(res.selected, k=inst["k"], fixed=inst["fixed"]) == []
    assert set(inst["fixed"]) <= set(res.selected) and not set(inst["forbidden"]) & set(res.selected)
    got = _score(inst, list(res.selected), mode, views, min_angle)
    assert got == pytest.approx(want, abs=1e-9), (res, want, inst)
    assert res.objective == pytest.approx(want, abs=1e-9), (res, want, inst)
    assert res.bound == pytest.approx(want, abs=1e-9) and res.gap == 0.0
    return res


_MODES = st.sampled_from([("quality", 2, None), ("multiview", 1, None), ("multiview", 2, None), ("multiview", 3, None),
                          ("multiview", 2, 50.0), ("multiview", 3, 20.0)])


@pytest.mark.parametrize("keep", list(_KEEP))
@settings(max_examples=40, **_SETTINGS)
@given(data=st.data())
def test_enumeration_matches_oracle(keep, data) -> None:
    inst = data.draw(graded_instances(keep))
    mode, views, angle = data.draw(_MODES)
    res = _check(inst, mode, "exact", views, angle)
    if res is not None and res.status == "optimal":
        assert res.stats["engine_choice"]["engine"] == "enumerate"


@pytest.mark.parametrize("keep", list(_KEEP))
@settings(max_examples=25, **_SETTINGS)
@given(data=st.data())
def test_scip_model_matches_oracle(keep, data) -> None:
    inst = data.draw(graded_instances(keep))
    mode, views, angle = data.draw(_MODES)
    res = _check(inst, mode, "mip", views, angle)
    if res is not None:
        assert res.engine == "mip" and res.stats["engine_choice"]["engine"] == "mip"


@settings(max_examples=30, **_SETTINGS)
@given(inst=graded_instances("combined"), how=_MODES)
def test_cpsat_model_matches_oracle(inst, how) -> None:
    _check(inst, how[0], "cpsat", how[1], how[2])


def test_each_constraint_binds_in_quality_and_multiview() -> None:
    """On one small case the unconstrained optimum breaks each constraint; with it the answer moves
    and still equals the oracle's, by the enumeration and by SCIP."""
    # 3 poses x 2 models; model 1 (expensive) sees more and better than model 0
    a0 = np.array([[1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [0, 1, 1]], dtype=np.float32) * 0.5
    a1 = np.array([[1, 1, 0], [1, 1, 0], [0, 1, 1], [0, 0, 1], [1, 1, 1]], dtype=np.float32)
    a = np.concatenate([a0, a1], axis=1)
    base = dict(a=a, w=np.array([1.0, 2.0, 1.0, 1.5, 0.5]), model=np.repeat([0, 1], 3), pose=np.tile(np.arange(3), 2),
                cost=np.repeat([1.0, 4.0], 3), model_limits=[(0, None), (0, None)], budget=None,
                zones=np.array([[False], [True], [False]] * 2), zone_limits=[(0, None)], one_per_pose=True,
                cardinality="exact", k=2, fixed=(), forbidden=(), n_models=2,
                pos=np.array([[0.0, 0, 0], [3, 0, 0], [0, 3, 0]] * 2), pts=np.full((5, 3), 0.5) + np.arange(5)[:, None])
    for mode, views in (("quality", 2), ("multiview", 2)):
        quota = [(1, None)] if mode == "quality" else [(0, 0)]  # the zone (pose 1): needed / kept free
        changes = {
            "counts": dict(model_limits=[(1, None), (0, None)]),
            "budget": dict(budget=6.0, cardinality="budget", k=None),
            "zones": dict(zone_limits=quota),
            "combined": dict(model_limits=[(1, 1), (0, None)], budget=6.0, cardinality="budget", k=None,
                             zone_limits=quota),
        }
        free = _oracle(base, mode, views, None)
        loose = _check(base, mode, "exact", views)
        for name, change in changes.items():
            inst = {**base, **change}
            assert not _ok(loose.selected, (), inst), (mode, name)  # the constraint binds
            want = _oracle(inst, mode, views, None)
            assert want is not None and want <= free
            for engine in ("exact", "mip"):
                _check(inst, mode, engine, views)


def test_engine_choice_names_the_mode() -> None:
    assert choose_team_engine("auto", 1e6, 20_000, "quality")[0] == "mip"
    assert "multiview" in choose_team_engine("auto", 1e6, 20_000, "multiview")[1]
    assert choose_team_engine("auto", 10, 20_000, "multiview")[0] == "enumerate"
    assert choose_team_engine("exact", 1e5, 20_000, "quality")[0] == "enumerate"
    # multiview with a minimum angle: the enumeration goes further under auto (the model's angle rows are many)
    assert choose_team_engine("auto", 3e5, 20_000, "multiview", angle=True)[0] == "enumerate"
    assert choose_team_engine("auto", 1e7, 20_000, "multiview", angle=True)[0] == "mip"
    assert choose_team_engine("mip", 10, 20_000, "multiview", angle=True)[0] == "mip"


def _large_team(m: int = 1500, n: int = 80):
    """A random graded matrix too big for the enumeration, and a two-model team with a budget and a zone."""
    from camplace.solver.problem.team import TeamConstraints

    q = sp.random(m, n, density=0.15, random_state=1, format="csr", dtype=np.float32)
    q.data = np.ceil(q.data * 4) / 4
    w = np.random.default_rng(1).random(m)
    half = n // 2
    team = TeamConstraints(model=np.repeat([0, 1], half), model_names=("a", "b"), model_min=(1, 1), model_max=(3, 2),
                           cost=np.repeat([1.0, 3.0], half), budget=8.0, cardinality="budget", zone_names=("z",),
                           zone_member=(np.arange(n) % 5 == 0)[:, None], zone_min=(1,), zone_max=(None,))
    return q, w, team


@pytest.mark.parametrize("mode", ["quality", "multiview"])
def test_team_model_under_a_time_limit_keeps_a_valid_answer(mode) -> None:
    """Beyond the enumeration, on a short time limit: the team route's answer meets the team, and
    status, objective, bound and gap agree (the bound at least the objective)."""
    q, w, team = _large_team()
    res = solve(q, w, options=SolveOptions(mode=mode, engine="auto", team=team, time_limit_s=1.0))
    assert res.stats["engine_choice"]["engine"] == "mip" and res.stats["engine_choice"]["route"] == "team"
    assert mode in res.stats["engine_choice"]["reason"]
    assert res.status in ("optimal", "feasible", "unknown")
    if res.status == "unknown":
        assert res.selected == () and math.isinf(res.gap)
        return
    assert team.violations(res.selected) == []
    assert res.bound >= res.objective - 1e-9 and res.gap >= 0.0
    if res.status == "optimal":
        assert res.gap == 0.0 and res.bound == res.objective
    else:
        assert res.gap > 0.0
    q_dense = q.toarray()
    sub = q_dense[:, list(res.selected)]
    want = float(w @ sub.max(axis=1)) if mode == "quality" else float(w[(sub > 0).sum(axis=1) >= 2].sum())
    assert res.objective == pytest.approx(want, abs=1e-9)


def test_team_model_too_big_under_auto_gives_the_greedy_team() -> None:
    """The one memory policy: a team model over the budget, not asked for by name, gives way to
    the greedy team (every constraint met) and the cheap bound, and says so."""
    q, w, team = _large_team()
    res = solve(q, w, options=SolveOptions(mode="quality", engine="auto", team=team, memory_budget_bytes=10**6))
    assert res.status in ("feasible", "optimal") and res.selected
    assert team.violations(res.selected) == []
    assert "team model of mode quality needs about" in res.stats["memory_fallback"]
    assert res.stats["answer"] == "greedy team: the model does not fit in memory"
    assert res.bound >= res.objective - 1e-9
    sub = q.toarray()[:, list(res.selected)]
    assert res.objective == pytest.approx(float(w @ sub.max(axis=1)), abs=1e-9)


def test_team_model_too_big_is_a_one_line_error() -> None:
    from camplace.errors import CamplaceError

    q, w, team = _large_team()
    with pytest.raises(CamplaceError, match="team model of mode quality needs about") as exc:
        solve(q, w, options=SolveOptions(mode="quality", engine="mip", team=team, memory_budget_bytes=10**6))
    assert "\n" not in str(exc.value)


# ----------------------------------------------------------------------------------------------
# a time limit: the greedy team, a valid bound (issue 31)
# ----------------------------------------------------------------------------------------------

_TIMED_MODES = st.sampled_from([("maxcover", 1, None), ("quality", 2, None), ("multiview", 1, None),
                                ("multiview", 2, None), ("multiview", 3, None)])


def _free(inst: dict) -> np.ndarray:
    """The allowed free columns as ``run_team`` sees them (a fixed camera's pose takes no other model)."""
    n = inst["model"].size
    free = [j for j in range(n) if j not in inst["fixed"] and j not in inst["forbidden"]]
    if inst["one_per_pose"] and inst["fixed"]:
        held = {int(inst["pose"][j]) for j in inst["fixed"]}
        free = [j for j in free if int(inst["pose"][j]) not in held]
    return np.array(free, dtype=np.int64)


@settings(max_examples=60, **_SETTINGS)
@given(inst=graded_instances("combined"), how=_TIMED_MODES)
def test_team_greedy_is_feasible_and_bound_valid(inst, how) -> None:
    """The greedy team meets every constraint, and so does its local search (never worse); the
    cheap bound is at least the oracle's optimum."""
    from camplace.solver._support.deadline import Deadline
    from camplace.solver.engines.team.greedy import improve_team, team_bound, team_greedy

    mode, views, _ = how
    if inst["k"] is None and inst["cardinality"] == "exact":
        return
    team = _constraints(inst)
    q = sp.csr_matrix(inst["a"])
    kw = dict(mode=mode, k=inst["k"], fixed=tuple(inst["fixed"]), free_cols=_free(inst))
    sel = team_greedy(q, inst["w"], team, conflicts=np.zeros((0, 2), np.int64), views=views, **kw)
    want = _oracle(inst, mode, views, None)
    if sel is not None:
        assert want is not None and _ok(sel, inst["fixed"], inst), (sel, inst)
        assert team.violations(sel, k=inst["k"], fixed=inst["fixed"]) == []
        assert set(inst["fixed"]) <= set(sel) and not set(inst["forbidden"]) & set(sel)
        # the local search keeps it feasible and never worse
        score = lambda s: _score(inst, list(s), mode, views, None)  # noqa: E731
        better, info = improve_team(sel, team, k=inst["k"], fixed=tuple(inst["fixed"]), free_cols=kw["free_cols"],
                                    conflicts=np.zeros((0, 2), np.int64), value=score, deadline=Deadline(None))
        assert _ok(better, inst["fixed"], inst) and set(inst["fixed"]) <= set(better)
        assert not set(inst["forbidden"]) & set(better)
        assert score(better) >= score(sel) - 1e-12 and info["evals"] >= 1
    if want is not None:
        assert team_bound(q, inst["w"], team, views=views, **kw) >= want - 1e-9, (mode, views, want, inst)


@pytest.mark.parametrize("engine", ["exact", "mip"])
@settings(max_examples=30, **_SETTINGS)
@given(inst=graded_instances("combined"), how=_TIMED_MODES)
def test_time_limit_gives_a_feasible_team_and_a_valid_bound(engine, inst, how) -> None:
    """The solve's deadline expires at its first check (the enumeration or the team model gets no
    time): the answer is a team meeting every constraint (the greedy one at worst) with a finite
    bound at least the oracle's optimum, or no team (status unknown / infeasible) when none is found."""
    from tests.solver._oracle import ExpiringDeadline, solve_deadline

    mode, views, angle = how
    if inst["k"] is None and inst["cardinality"] == "exact":
        return
    want = _oracle(inst, mode, views, angle)
    extra = dict(views=views) if mode == "multiview" else {}
    opts = SolveOptions(mode=mode, k=inst["k"], engine=engine, fixed=inst["fixed"], forbidden=inst["forbidden"],
                        team=_constraints(inst), time_limit_s=1.0, **extra)
    with pytest.MonkeyPatch.context() as mp:
        solve_deadline(mp, ExpiringDeadline(0))
        res = solve(sp.csr_matrix(inst["a"]), inst["w"], options=opts)
    if res.status in ("unknown", "infeasible"):  # (an empty team may be a feasible answer)
        assert res.selected == () and math.isinf(res.gap)
        if res.status == "infeasible":
            assert want is None
        return
    assert want is not None
    assert _ok(res.selected, inst["fixed"], inst), (res.selected, inst)
    assert _constraints(inst).violations(res.selected, k=inst["k"], fixed=inst["fixed"]) == []
    assert res.status in ("optimal", "feasible")
    assert res.objective == pytest.approx(_score(inst, list(res.selected), mode, views, angle), abs=1e-9)
    assert math.isfinite(res.bound) and res.bound >= want - 1e-9 and res.bound >= res.objective - 1e-9
    assert res.gap >= 0.0 and (res.gap == 0.0) == (res.status == "optimal")


@pytest.mark.parametrize("mode", ["quality", "multiview", "maxcover"])
def test_team_model_build_interrupted_returns_the_greedy_team(mode) -> None:
    """The time limit passes while the team model is being built (or before it is solved): the
    answer is the greedy team (status feasible, a finite bound at least its value), not "unknown"."""
    from tests.solver._oracle import ExpiringDeadline, solve_deadline

    q, w, team = _large_team()
    with pytest.MonkeyPatch.context() as mp:
        solve_deadline(mp, ExpiringDeadline(0))
        res = solve(q, w, options=SolveOptions(mode=mode, engine="mip", team=team, time_limit_s=1.0))
    assert res.status == "feasible" and res.selected, res
    assert team.violations(res.selected) == []
    assert res.stats["answer"].startswith("greedy team")
    assert res.objective == pytest.approx(res.stats["hint_value"])
    assert math.isfinite(res.bound) and res.bound >= res.objective and 0.0 < res.gap < 1.0


@settings(max_examples=200, **_SETTINGS)
@given(inst=graded_instances("combined"), views=st.integers(2, 3))
def test_largest_team_and_shared_bound_hold_for_every_team(inst, views) -> None:
    """``largest_team`` is at least the new cameras of every feasible team, and the shared-sighting
    bound over the fixed and at most that many allowed columns is at least the multiview optimum
    (both against the enumeration of every team)."""
    from camplace.solver.engines.team.greedy import largest_team, shared_bound

    if inst["k"] is None and inst["cardinality"] == "exact":
        return
    team = _constraints(inst)
    fixed = tuple(inst["fixed"])
    free = _free(inst)
    n = inst["model"].size
    allowed = [j for j in range(n) if j not in inst["fixed"] and j not in inst["forbidden"]]
    teams = [list(fixed) + list(c) for r in range(len(allowed) + 1) for c in itertools.combinations(allowed, r)
             if _ok(list(fixed) + list(c), fixed, inst)]
    if not teams:
        return
    r = largest_team(team, inst["k"], fixed, free)
    assert r >= max(len(t) - len(fixed) for t in teams), (r, inst)
    best = max(_score(inst, t, "multiview", views, None) for t in teams)
    got = shared_bound(sp.csr_matrix(inst["a"]), inst["w"], team, np.union1d(free, np.asarray(fixed, dtype=np.int64)),
                       r + len(fixed), views)
    assert got >= best - 1e-9, (got, best, views, inst)


def test_multiview_team_bound_on_the_large_team() -> None:
    """On the random 1,500 x 80 team (four cameras at most: three of model a and one of b within the
    budget) the cheap multiview bound is the shared-sighting one, below the column-sum bound and at
    least the best team the solver finds."""
    from camplace.solver.engines.team.greedy import largest_team, shared_bound, team_bound

    q, w, team = _large_team()
    free = np.arange(q.shape[1])
    assert largest_team(team, None, (), free) == 4  # 3 x cost 1 + 1 x cost 3 <= 8 < 3 + 2 x 3
    got = team_bound(q, w, team, mode="multiview", k=None, fixed=(), free_cols=free, views=2)
    col = np.asarray((q > 0).multiply(w[:, None]).sum(axis=0)).ravel()
    assert got == pytest.approx(shared_bound(q, w, team, free, 4, 2), rel=1e-12)
    assert got < np.sort(col)[::-1][:4].sum() / 2
    res = solve(q, w, options=SolveOptions(mode="multiview", engine="auto", team=team, time_limit_s=1.0))
    if res.selected:
        assert got >= res.objective - 1e-9 and res.bound <= got + 1e-9
