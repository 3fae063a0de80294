"""Camera teams in the solver (issue 31): every constraint and objective against enumeration.

The oracle below checks the constraints itself (it does not call ``TeamConstraints.violations``)
and enumerates every subset of the allowed columns; each engine (the exact enumeration, SCIP,
CP-SAT) must reach its optimum, meet every constraint, and agree on infeasibility.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.errors import CamplaceError
from camplace.solver.api import solve
from camplace.solver.options import SolveOptions
from camplace.solver.problem.team import TeamConstraints, pose_index
from camplace.solver.routes import choose_team_engine

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _ok(sel, fixed, inst) -> bool:
    """Independent check of every constraint on a full selection (fixed included)."""
    model, cost, zones, pose = inst["model"], inst["cost"], inst["zones"], inst["pose"]
    sel = list(sel)
    for mi, (lo, hi) in enumerate(inst["model_limits"]):
        c = sum(1 for j in sel if model[j] == mi)
        if c < lo or (hi is not None and c > hi):
            return False
    if inst["budget"] is not None and sum(cost[j] for j in sel) > inst["budget"] + 1e-9:
        return False
    for zi, (lo, hi) in enumerate(inst["zone_limits"]):
        c = sum(1 for j in sel if zones[j, zi])
        if c < lo or (hi is not None and c > hi):
            return False
    if inst["one_per_pose"] and len({pose[j] for j in sel}) < len(sel):
        return False
    new = len(set(sel) - set(fixed))
    if inst["k"] is not None:
        if inst["cardinality"] == "exact" and new != inst["k"]:
            return False
        if inst["cardinality"] == "budget" and new > inst["k"]:
            return False
    return True


def _oracle(inst, mode: str):
    """(best objective or None when infeasible) by enumerating every subset of the allowed columns."""
    a = inst["a"] > 0
    w = inst["w"]
    fixed, forbidden = inst["fixed"], inst["forbidden"]
    n = a.shape[1]
    free = [j for j in range(n) if j not in fixed and j not in forbidden]
    # coverable: by a camera that could be in a team (a column at a fixed camera's pose could not)
    held = {inst["pose"][j] for j in fixed} if inst["one_per_pose"] else set()
    usable = list(fixed) + [j for j in free if inst["pose"][j] not in held]
    coverable = np.array([any(a[i, j] for j in usable) for i in range(len(w))], dtype=bool)
    best = None
    for r in range(len(free) + 1):
        for combo in itertools.combinations(free, r):
            sel = list(fixed) + list(combo)
            if not _ok(sel, fixed, inst):
                continue
            cov = a[:, sel].any(axis=1) if sel else np.zeros(len(w), bool)
            if mode == "maxcover":
                v = float(w[cov].sum())
                best = v if best is None or v > best else best
            else:
                frac = inst.get("frac", 1.0)
                if frac >= 1.0 and np.any(coverable & (w > 0) & ~cov):
                    continue
                if frac < 1.0 and w[cov & coverable].sum() < frac * w[coverable].sum() * (1 - 1e-12) - 1e-12:
                    continue
                v = float(sum(inst["cost"][j] for j in combo))
                best = v if best is None or v < best else best
    return best


@st.composite
def team_instances(draw):
    n_poses = draw(st.integers(2, 4))
    n_models = draw(st.integers(1, 2))
    # each pose offered with a non-empty subset of the models; columns model-major (as the sampler)
    offered = [[p for p in range(n_poses) if draw(st.booleans()) or mi == 0] for mi in range(n_models)]
    model = np.array([mi for mi in range(n_models) for _ in offered[mi]], dtype=np.int64)
    pose = np.array([p for mi in range(n_models) for p in offered[mi]], dtype=np.int64)
    n = model.size
    m = draw(st.integers(0, 8))
    bits = draw(st.lists(st.booleans(), min_size=m * n, max_size=m * n))
    a = np.array(bits, dtype=np.float32).reshape(m, n)
    w = np.array(draw(st.lists(st.sampled_from([0.0, 0.5, 1.0, 2.0, 3.25]), min_size=m, max_size=m)))
    model_cost = [draw(st.sampled_from([0.0, 1.0, 2.0, 3.0, 5.0])) for _ in range(n_models)]
    cost = np.array([model_cost[mi] for mi in model], dtype=np.float64)
    limits = []
    for _ in range(n_models):
        lo = draw(st.integers(0, 2))
        hi = draw(st.one_of(st.none(), st.integers(lo, 3)))
        limits.append((lo, hi) if draw(st.booleans()) else (0, None))
    budget = draw(st.one_of(st.none(), st.sampled_from([0.0, 2.0, 4.0, 6.0, 9.0])))
    n_zones = draw(st.integers(0, 2))
    pose_zone = np.array(draw(st.lists(st.booleans(), min_size=n_poses * n_zones, max_size=n_poses * n_zones)),
                         dtype=bool).reshape(n_poses, n_zones)
    zones = pose_zone[pose] if n_zones else np.zeros((n, 0), bool)
    zone_limits = []
    for _ in range(n_zones):
        lo = draw(st.integers(0, 2))
        zone_limits.append((lo, draw(st.one_of(st.none(), st.integers(lo, 2)))))
    one_per_pose = draw(st.booleans())
    cardinality = draw(st.sampled_from(["exact", "budget"]))
    k = draw(st.integers(0, 3)) if cardinality == "exact" else draw(st.one_of(st.none(), st.integers(0, 3)))
    fixed = tuple(sorted(set(draw(st.lists(st.integers(0, n - 1), max_size=1)))))
    forbidden = tuple(j for j in sorted(set(draw(st.lists(st.integers(0, n - 1), max_size=2)))) if j not in fixed)
    free = n - len(fixed) - len(forbidden)
    if cardinality == "exact" and k is not None:
        k = min(k, free)
    if not fixed and cardinality == "exact" and k == 0:
        k = min(1, free)
    frac = draw(st.sampled_from([1.0, 1.0, 0.5]))  # setcover: the share of the coverable weight to observe
    return dict(a=a, w=w, model=model, pose=pose, cost=cost, model_limits=limits, budget=budget, zones=zones,
                zone_limits=zone_limits, one_per_pose=one_per_pose, cardinality=cardinality, k=k, fixed=fixed,
                forbidden=forbidden, n_models=n_models, frac=frac)


def _constraints(inst) -> TeamConstraints:
    return TeamConstraints(
        model=inst["model"], model_names=tuple(f"m{i}" for i in range(inst["n_models"])),
        model_min=tuple(lo for lo, _ in inst["model_limits"]), model_max=tuple(hi for _, hi in inst["model_limits"]),
        cost=inst["cost"], budget=inst["budget"], zone_names=tuple(f"z{i}" for i in range(len(inst["zone_limits"]))),
        zone_member=inst["zones"], zone_min=tuple(lo for lo, _ in inst["zone_limits"]),
        zone_max=tuple(hi for _, hi in inst["zone_limits"]), pose=inst["pose"] if inst["one_per_pose"] else None,
        cardinality=inst["cardinality"])


def _solve(inst, mode: str, engine: str, fmt: str = "csr"):
    k = None if mode == "setcover" else inst["k"]
    frac = inst.get("frac", 1.0) if mode == "setcover" else 1.0
    if engine == "cpsat":
        frac = 1.0  # CP-SAT has no weighted coverage row (a one-line error, tested below)
    opts = SolveOptions(mode=mode, k=k, engine=engine, fixed=inst["fixed"], forbidden=inst["forbidden"],
                        required_fraction=frac, team=_constraints(inst))
    matrix = sp.csr_matrix(inst["a"])
    if fmt == "bits":  # a binary matrix as column bitsets, as a binary run stores it
        from camplace.visibility.bits import bits_from_csr

        matrix = bits_from_csr(matrix)
    return solve(matrix, inst["w"], options=opts)


def _agree(inst, mode: str, engine: str) -> None:
    if mode == "maxcover" and inst["k"] is None and inst["cardinality"] == "exact":
        return
    if mode == "setcover":
        inst = {**inst, "k": None}
    if engine == "cpsat":
        inst = {**inst, "frac": 1.0}
    want = _oracle(inst, mode)
    res = _solve(inst, mode, engine)
    if want is None:
        assert res.status == "infeasible", (res, inst)
        assert res.selected == () and math.isnan(res.objective)
        return
    assert res.status == "optimal", (res, want, inst)
    assert _ok(res.selected, inst["fixed"], inst), (res.selected, inst)
    assert set(inst["fixed"]) <= set(res.selected) and not set(inst["forbidden"]) & set(res.selected)
    assert res.objective == pytest.approx(want, abs=1e-9), (res, want, inst)
    assert res.bound == pytest.approx(want, abs=1e-9) and res.gap == 0.0
    assert res.stats["engine_choice"]["route"] == "team"


@settings(max_examples=120, **_SETTINGS)
@given(team_instances(), st.sampled_from(["maxcover", "setcover"]))
def test_enumeration_matches_oracle(inst, mode) -> None:
    _agree(inst, mode, "exact")


@settings(max_examples=60, **_SETTINGS)
@given(team_instances(), st.sampled_from(["maxcover", "setcover"]))
def test_scip_model_matches_oracle(inst, mode) -> None:
    _agree(inst, mode, "mip")


@settings(max_examples=25, **_SETTINGS)
@given(team_instances(), st.sampled_from(["maxcover", "setcover"]))
def test_cpsat_model_matches_oracle(inst, mode) -> None:
    _agree(inst, mode, "cpsat")


# -- each constraint binds alone (the unconstrained optimum breaks it) --------------------------------


def _base():
    # 4 poses x 2 models; model 1 sees everything its pose's model-0 column sees, and more
    a0 = np.array([[1, 0, 0, 0], [1, 1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float32)
    a1 = a0.copy()
    a1[2, 0] = a1[0, 1] = a1[4, 2] = 1
    a = np.concatenate([a0, a1], axis=1)
    return dict(a=a, w=np.array([1.0, 1.0, 2.0, 1.5, 0.5]), model=np.repeat([0, 1], 4), pose=np.tile(np.arange(4), 2),
                cost=np.repeat([1.0, 4.0], 4), model_limits=[(0, None), (0, None)], budget=None,
                zones=np.zeros((8, 0), bool), zone_limits=[], one_per_pose=False, cardinality="exact", k=2, fixed=(),
                forbidden=(), n_models=2)


@pytest.mark.parametrize("change", [
    dict(model_limits=[(0, None), (0, 0)]),                 # no model-1 camera
    dict(model_limits=[(2, None), (0, None)]),              # at least two model-0 cameras
    dict(budget=5.0, cardinality="budget", k=None),         # any number within the budget
    dict(one_per_pose=True, w=np.array([5.0, 5.0, 1.0, 1.5, 0.5]),  # one camera per pose: both models at pose 0
         a=np.array([[1, 0, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 1, 0, 0, 0], [0, 1, 1, 1, 0, 1, 1, 1], [0, 0, 0, 0, 0, 0, 0, 0],
                     [0, 0, 0, 0, 0, 0, 0, 0]], dtype=np.float32)),
    dict(zones=np.array([[0], [0], [0], [1]] * 2, dtype=bool), zone_limits=[(1, None)]),  # a quota at pose 3
    dict(zones=np.array([[1], [1], [0], [0]] * 2, dtype=bool), zone_limits=[(0, 0)]),     # nothing in zone 0..1
], ids=["model-max", "model-min", "budget", "pose", "zone-min", "zone-max"])
def test_each_constraint_binds(change) -> None:
    inst = {**_base(), **change}
    free = {**inst, "one_per_pose": False}
    unconstrained = _solve({**free, "model_limits": [(0, None)] * 2, "budget": None, "zone_limits": [(0, None)] * len(
        inst["zone_limits"]), "cardinality": "exact", "k": 2}, "maxcover", "exact")
    assert not _ok(unconstrained.selected, (), inst), "the case must bind"
    for engine in ("exact", "mip"):
        _agree(inst, "maxcover", engine)


def test_no_dominance_across_models() -> None:
    """Column 0 (model 0) sees a superset of column 4 (model 1) at the same cost; with one model-1
    camera required the model-1 column must still be there to choose."""
    a = np.array([[1, 0, 0, 1, 1], [1, 0, 1, 0, 0], [0, 1, 0, 0, 0]], dtype=np.float32)
    a = np.concatenate([a, np.array([[1], [0], [0]], dtype=np.float32)], axis=1)  # column 5: model 1
    t = TeamConstraints(model=[0, 0, 0, 0, 0, 1], model_names=("a", "b"), model_min=(0, 1), model_max=(None, None),
                        cost=np.ones(6))
    for engine in ("auto", "exact", "mip"):
        res = solve(sp.csr_matrix(a), np.ones(3), options=SolveOptions(k=2, engine=engine, team=t))
        assert res.status == "optimal" and 5 in res.selected and res.objective == 2.0


def test_infeasible_quota() -> None:
    inst = {**_base(), "zones": np.zeros((8, 1), bool), "zone_limits": [(1, None)]}  # no pose stands in the zone
    for engine in ("auto", "exact", "mip", "cpsat"):
        res = _solve(inst, "maxcover", engine)
        assert res.status == "infeasible" and res.selected == () and res.gap == math.inf
        assert res.to_dict()["objective"] is None


def test_setcover_uses_the_model_costs() -> None:
    # column 4 (model 1, cost 4) covers rows 0..2 alone; columns 0 and 2 (cost 1 each) cover them too
    a = np.array([[1, 0, 0, 0, 1], [0, 0, 1, 0, 1], [1, 0, 1, 0, 1]], dtype=np.float32)
    t = TeamConstraints(model=[0, 0, 0, 0, 1], model_names=("a", "b"), model_min=(0, 0), model_max=(None, None),
                        cost=[1, 1, 1, 1, 4])
    for engine in ("exact", "mip"):
        res = solve(sp.csr_matrix(a), np.ones(3), options=SolveOptions(mode="setcover", engine=engine, team=t))
        assert res.status == "optimal" and res.selected == (0, 2) and res.objective == 2.0


def test_engine_choice_is_recorded() -> None:
    assert choose_team_engine("auto", 100, 20_000)[0] == "enumerate"
    name, reason = choose_team_engine("auto", 1e9, 20_000)
    assert name == "bnb" and "1e+09" in reason
    assert choose_team_engine("auto", 1e9, 20_000, "setcover")[0] == "mip"
    assert choose_team_engine("auto", 1e9, 20_000, "maxcover", conflicts=3)[0] == "mip"
    assert choose_team_engine("cpsat", 10, 20_000)[0] == "cpsat"
    assert choose_team_engine("exact", 1e5, 20_000, "setcover")[0] == "enumerate"
    with pytest.raises(CamplaceError, match="no exact team engine"):
        choose_team_engine("exact", 1e9, 20_000, "setcover")


@pytest.mark.parametrize("fmt", ["csr", "bits"])
@pytest.mark.parametrize("patterns", [True, False], ids=["patterns", "whole-team"])
@settings(max_examples=100, **_SETTINGS)
@given(inst=team_instances())
def test_branch_and_bound_matches_oracle(inst, patterns, fmt) -> None:
    """The large-instance route at small sizes: per-model count patterns (single-model ones by the
    k-camera engines, mixed ones by the branch and bound), or the branch and bound on the whole team;
    on a scipy matrix and on column bitsets (the row lists and the single-model patterns read from
    the bits, no CSR copy), with the same answer."""
    if inst["k"] is None and inst["cardinality"] == "exact":
        return
    import camplace.solver.engines.team.enumeration as en
    import camplace.solver.engines.team.patterns as pt

    saved = en.ENUMERATION_LIMIT, pt.MAX_PATTERNS
    en.ENUMERATION_LIMIT = -1
    if not patterns:
        pt.MAX_PATTERNS = -1
    try:
        want = _oracle(inst, "maxcover")
        res = _solve(inst, "maxcover", "auto", fmt)
        if fmt == "bits":
            assert res.stats["matrix"] == "column bitsets (no CSR copy)"
            other = _solve(inst, "maxcover", "auto")
            assert (res.selected, res.status) == (other.selected, other.status), (res, other, inst)
    finally:
        en.ENUMERATION_LIMIT, pt.MAX_PATTERNS = saved
    assert res.stats["engine_choice"]["engine"] == "bnb"
    if not patterns:
        assert "patterns" not in res.stats["engine_stats"]
    if want is None:
        assert res.status == "infeasible", (res, inst)
        return
    assert res.status == "optimal", (res, want, inst)
    assert _ok(res.selected, inst["fixed"], inst), (res.selected, inst)
    assert res.objective == pytest.approx(want, abs=1e-9), (res, want, inst)


@settings(max_examples=150, **_SETTINGS)
@given(inst=team_instances())
def test_count_bound_is_at_least_the_best_team(inst) -> None:
    """The branch and bound's row-free bound (column counts x the largest weight, per model) is never
    below the enumerated optimum of max coverage under the team's constraints."""
    from camplace.solver.engines.team.bnb import count_bound
    from camplace.visibility.bits import bits_from_csr

    if inst["k"] is None and inst["cardinality"] == "exact":
        return
    want = _oracle(inst, "maxcover")
    if want is None:
        return
    n = inst["a"].shape[1]
    free = np.array([j for j in range(n) if j not in inst["fixed"] and j not in inst["forbidden"]], dtype=np.int64)
    got = count_bound(bits_from_csr(sp.csr_matrix(inst["a"])), inst["w"], _constraints(inst), inst["k"],
                      inst["fixed"], free)
    assert got >= want - 1e-12, (got, want, inst)


def test_pose_index_matches_position_and_rotation() -> None:
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0], [1, 0, 0], [0, 0, 0]], dtype=float)
    rot = np.tile(np.eye(3), (5, 1, 1))
    rot[4] = np.diag([1.0, -1.0, -1.0])  # same position, another rotation: another pose
    assert pose_index(pos, rot).tolist() == [0, 1, 0, 1, 2]


def test_options_check_the_team() -> None:
    t = TeamConstraints(model=[0, 0], model_names=("a",), model_min=(0,), model_max=(None,), cost=[1, 1])
    # every mode enforces a team (quality and multiview too: tests/solver/test_solver_team_modes.py)
    for mode in ("maxcover", "quality", "multiview"):
        assert SolveOptions(mode=mode, k=1, team=t).team is t
    with pytest.raises(CamplaceError, match="describe 2 candidate columns"):
        solve(sp.csr_matrix(np.ones((2, 3))), np.ones(2), options=SolveOptions(k=1, team=t))
    with pytest.raises(CamplaceError, match="shape"):
        TeamConstraints(model=[0, 0], model_names=("a",), model_min=(0,), model_max=(None,), cost=[1, 1],
                        zone_names=("z",), zone_member=np.zeros((3, 1), bool), zone_min=(0,), zone_max=(None,))
    assert SolveOptions(k=1, team=t).record()["team"]["models"] == [{"name": "a", "min_count": 0, "max_count": None}]
    with pytest.raises(CamplaceError, match="use engine mip"):
        solve(sp.csr_matrix(np.eye(2, dtype=np.float32)), np.ones(2),
              options=SolveOptions(mode="setcover", required_fraction=0.5, engine="cpsat", team=t))


@settings(max_examples=40, **_SETTINGS)
@given(team_instances(), st.sampled_from(["maxcover", "setcover"]), st.sampled_from(["exact", "mip"]))
def test_minimum_distance_with_a_team(inst, mode, engine) -> None:
    """Minimum distance on top of the team: poses 1 m apart on a line, 1.5 m apart required (so
    neighbouring poses conflict); the enumeration and SCIP against the oracle that checks it too."""
    if mode == "maxcover" and inst["k"] is None and inst["cardinality"] == "exact":
        return
    if mode == "setcover":
        inst = {**inst, "k": None}
    pos = np.column_stack([inst["pose"].astype(float), np.zeros(inst["pose"].size), np.zeros(inst["pose"].size)])
    spaced = {**inst, "one_per_pose": True}  # two models at one pose stand 0 m apart: they conflict anyway
    fixed = inst["fixed"]

    def spaced_ok(sel) -> bool:
        p = [pos[j, 0] for j in sel]
        return all(abs(a - b) >= 1.5 for i, a in enumerate(p) for b in p[i + 1:])

    # the oracle on the columns no fixed camera conflicts with (as the solver: those are banned)
    banned = {j for j in range(pos.shape[0]) for f in fixed if j != f and abs(pos[j, 0] - pos[f, 0]) < 1.5}
    if not spaced_ok(fixed):
        return  # fixed cameras closer than the distance: a one-line error, not a team question
    oracle_inst = {**spaced, "forbidden": tuple(sorted(set(inst["forbidden"]) | (banned - set(fixed))))}
    best = None
    a = oracle_inst["a"] > 0
    w = oracle_inst["w"]
    n = a.shape[1]
    free = [j for j in range(n) if j not in fixed and j not in oracle_inst["forbidden"]]
    usable = list(fixed) + free
    coverable = np.array([any(a[i, j] for j in usable) for i in range(len(w))], dtype=bool)
    for r in range(len(free) + 1):
        for combo in itertools.combinations(free, r):
            sel = list(fixed) + list(combo)
            if not (_ok(sel, fixed, oracle_inst) and spaced_ok(sel)):
                continue
            cov = a[:, sel].any(axis=1) if sel else np.zeros(len(w), bool)
            if mode == "maxcover":
                v = float(w[cov].sum())
                best = v if best is None or v > best else best
            elif not np.any(coverable & (w > 0) & ~cov):
                v = float(sum(inst["cost"][j] for j in combo))
                best = v if best is None or v < best else best
    k = None if mode == "setcover" else inst["k"]
    try:
        res = solve(sp.csr_matrix(inst["a"]), inst["w"], positions=pos,
                    options=SolveOptions(mode=mode, k=k, engine=engine, fixed=fixed, forbidden=inst["forbidden"],
                                         min_distance_m=1.5, team=_constraints(spaced)))
    except CamplaceError as exc:  # more new cameras asked than the spacing leaves: the api's one-line error
        assert "cannot choose k=" in str(exc) and best is None
        return
    if best is None:
        assert res.status == "infeasible", (res, inst)
        return
    assert res.status == "optimal" and spaced_ok(res.selected) and _ok(res.selected, fixed, spaced), (res, inst)
    assert res.objective == pytest.approx(best, abs=1e-9), (res, best, inst)


def test_from_team_on_the_builtin_team() -> None:
    """comet-67p-team's candidates: each model's columns, costs, zones and the shared poses."""
    from camplace.instance import builtin
    from camplace.solver.problem.team import team_options
    from camplace.visibility.stages import make_run_candidates, stage_seeds

    inst = builtin("comet-67p-team")
    cands = make_run_candidates(inst, "chaotic", 60, 1, stage_seeds(0)[0])
    t = TeamConstraints.from_team(inst.team, cands)
    assert t.cardinality == "budget" and t.budget == 8000.0 and t.model_names == ("wide", "science")
    assert np.array_equal(t.model, cands.model) and np.array_equal(t.cost, np.where(cands.model == 0, 900.0, 6000.0))
    assert t.zone_member.shape == (len(cands), 2) and np.array_equal(t.zone_member, cands.zones)
    # a pose offered to both models: the same index, and distinct poses get distinct ones
    shared = 0
    for j in np.flatnonzero(cands.model == 1):
        same = np.flatnonzero((t.pose == t.pose[j]) & (np.arange(len(cands)) != j))
        for i in same:
            assert np.array_equal(cands.positions[i], cands.positions[j]) and cands.model[i] == 0
            shared += 1
    assert shared > 0
    assert len(np.unique(t.pose)) == len({(tuple(p), tuple(r.ravel())) for p, r in zip(cands.positions, cands.rotations)})
    # the options: budget cardinality drops k, in every mode (quality and multiview enforce teams too)
    for mode in ("maxcover", "quality", "multiview"):
        o = team_options(inst.team, cands, SolveOptions(mode=mode, k=3))
        assert o.team is not None and o.k is None and o.mode == mode
    assert team_options(None, cands, SolveOptions(mode="quality", k=3)).team is None


@pytest.mark.parametrize("seed", [0, 1])
def test_branch_and_bound_bound_is_valid_under_a_time_limit(seed) -> None:
    """A mid-size team (60 poses x 2 models, a zone quota, k = 4): the branch and bound proves
    SCIP's optimum without a limit, and under a tiny limit keeps a bound no lower than it."""
    rng = np.random.default_rng(seed)
    n_poses, m = 60, 200
    a = sp.csr_matrix((rng.random((m, 2 * n_poses)) < 0.08).astype(np.float32))
    w = rng.random(m)
    zones = np.zeros((2 * n_poses, 1), dtype=bool)
    zones[np.r_[0:8, n_poses:n_poses + 8], 0] = True
    t = TeamConstraints(model=np.repeat([0, 1], n_poses), model_names=("a", "b"), model_min=(1, 1), model_max=(3, 2),
                        cost=np.repeat([1.0, 2.0], n_poses), zone_names=("z",), zone_member=zones, zone_min=(1,),
                        zone_max=(None,), pose=np.tile(np.arange(n_poses), 2))
    ref = solve(a, w, options=SolveOptions(k=4, engine="mip", team=t))
    assert ref.status == "optimal"
    full = solve(a, w, options=SolveOptions(k=4, team=t))
    assert full.stats["engine_choice"]["engine"] == "bnb"
    assert full.status == "optimal" and full.objective == pytest.approx(ref.objective, abs=1e-9)

    # larger (150 poses, k = 5): proven without a limit, cut short by 0.05 s with a valid bound
    n_poses, m = 150, 400
    a = sp.csr_matrix((rng.random((m, 2 * n_poses)) < 0.1).astype(np.float32))
    w = rng.random(m)
    zones = np.zeros((2 * n_poses, 1), dtype=bool)
    zones[np.r_[0:8, n_poses:n_poses + 8], 0] = True
    t = replace(t, model=np.repeat([0, 1], n_poses), model_max=(3, 3), cost=np.repeat([1.0, 2.0], n_poses),
                zone_member=zones, pose=np.tile(np.arange(n_poses), 2))
    full = solve(a, w, options=SolveOptions(k=5, team=t))
    assert full.status == "optimal"
    solve(a, w, options=SolveOptions(k=5, team=t, time_limit_s=0.05))  # warm (imports)
    quick = solve(a, w, options=SolveOptions(k=5, team=t, time_limit_s=0.05))
    assert quick.status in ("optimal", "feasible") and not t.violations(quick.selected, k=5)
    assert quick.bound >= full.objective - 1e-9 and quick.objective <= full.objective + 1e-9
    if quick.status == "feasible":
        assert quick.gap > 0 and any(p["status"] != "optimal" for p in quick.stats["engine_stats"]["patterns"])


def test_team_record_says_whether_the_solver_enforced() -> None:
    from camplace.instance import builtin
    from camplace.solution import team_record

    inst = builtin("comet-67p-team")
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    cams = [{"model": "wide", "cost": 900.0, "zones": ["upstream"], "position": [1.0, 1.0, 1.0], "rotation": eye},
            {"model": "science", "cost": 6000.0, "zones": ["downstream"], "position": [15.0, 1.0, 1.0], "rotation": eye}]
    rec, notes = team_record(inst, cams, enforced=True, cardinality="budget")
    assert rec["enforced"] is True and rec["cardinality"] == "budget" and rec["broken"] == [] and notes == []
    assert rec["uses"] == {"models": {"wide": 1, "science": 1}, "cost": 6900.0, "zones": {"upstream": 1, "downstream": 1}}
    rec, notes = team_record(inst, cams[:1], why_not="by the robust placement")
    assert rec["enforced"] is False and rec["broken"] == ["0 camera(s) in zone downstream (asked 1+)"]
    assert notes[0].startswith("team: the per-model counts, the budget and the zone quotas are not enforced by the robust")
    _, notes = team_record(inst, [cams[0], {**cams[0], "candidate": 9}], enforced=True, cardinality="budget")
    assert "two cameras share a pose" in notes[0]  # said loudly, never expected


def test_branch_and_bound_stops_at_the_time_limit_within_a_few_nodes() -> None:
    """Past the time limit the branch and bound visits no more nodes, not even ones its bound would
    prune (each costs the gains of every column: on comet-67p-team's robust scenarios a 10 s limit
    took 47 s), and its bound stays at least the optimum."""
    from camplace.solver.engines.team.bnb import team_branch_and_bound
    from tests.solver._oracle import CountingDeadline

    rng = np.random.default_rng(3)
    n_poses, m, k = 150, 400, 5
    a = sp.csr_matrix((rng.random((m, 2 * n_poses)) < 0.1).astype(np.float32))
    w = rng.random(m)
    t = TeamConstraints(model=np.repeat([0, 1], n_poses), model_names=("a", "b"), model_min=(1, 1), model_max=(3, 3),
                        cost=np.repeat([1.0, 2.0], n_poses), zone_names=(), zone_member=np.zeros((2 * n_poses, 0), bool),
                        zone_min=(), zone_max=(), pose=np.tile(np.arange(n_poses), 2))
    free = np.arange(2 * n_poses)
    full = team_branch_and_bound(a, w, t, k=k, fixed=(), free_cols=free, deadline=CountingDeadline(10**9))
    assert full[1] == "optimal" and full[4]["nodes"] > 200
    for after in (1, 20, 100):
        sel, status, value, bound, st = team_branch_and_bound(a, w, t, k=k, fixed=(), free_cols=free,
                                                              deadline=CountingDeadline(after))
        assert st["timed_out"] and st["nodes"] <= after + 2 * k + 2, (after, st["nodes"])
        assert bound >= full[2] - 1e-9 and (sel is None or value <= full[2] + 1e-9)
