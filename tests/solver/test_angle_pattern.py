"""A minimum angle off the bits routes (issue 32): the general model (engine mip / cpsat, or a
minimum distance) and a camera team read the binary matrix as its bool CSR pattern, never as float
values. The answer equals the float32 CSR route's and the enumerated optimum, for a bool CSR and
for column bitsets, with the float conversion made to fail."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.api as api
from camplace.solver.api import bits_solve_bytes, solve
from camplace.solver.options import SolveOptions
from camplace.solver.problem.team import TeamConstraints
from camplace.visibility.bits import bits_from_csr
from tests.solver._oracle import brute_force_mode


def _case(seed: int):
    """(dense (m, n) float32 0/1, weights (m,), camera positions (n, 3) m, points (m, 3) m)."""
    rng = np.random.default_rng(seed)
    m, n = 48, 10
    dense = (rng.random((m, n)) < 0.45).astype(np.float32)
    w = np.where(rng.random(m) < 0.15, 0.0, rng.random(m) + 0.1)
    return dense, w, rng.normal(size=(n, 3)) * 5.0, rng.normal(size=(m, 3))


def _no_floats(mp) -> None:
    """Make the pattern's float conversion fail (the routes here must not make one)."""
    def refused(matrix):
        raise AssertionError("a bool pattern was converted to float values")

    mp.setattr(api, "float_values", refused)


_KWS = [
    dict(engine="mip"),
    dict(engine="cpsat"),
    dict(engine="auto", min_distance_m=6.0),
    dict(engine="mip", min_distance_m=6.0, fixed=(1,)),
    dict(engine="auto", forbidden=(2, 5), views=3),
]


@pytest.mark.parametrize("kw", _KWS)
def test_min_angle_general_model_reads_the_pattern(kw, monkeypatch) -> None:
    for seed in (1, 2):
        dense, w, pos, pts = _case(seed)
        args = dict(k=3, mode="multiview", views=2, min_angle_deg=25.0, positions=pos, points=pts, time_limit_s=60)
        args.update(kw)
        ref = solve(sp.csr_matrix(dense), w, **args)
        best = brute_force_mode(dense, w, args["k"], "multiview", views=args["views"], min_angle_deg=25.0, pos=pos,
                                pts=pts, fixed=args.get("fixed", ()), forbidden=args.get("forbidden", ()),
                                dmin=args.get("min_distance_m"))
        assert ref.status == "optimal" and ref.objective == pytest.approx(best, rel=1e-12)
        for mat in (sp.csr_matrix(dense).astype(bool), bits_from_csr(sp.csr_matrix(dense))):
            with monkeypatch.context() as mp:
                _no_floats(mp)
                got = solve(mat, w, **args)
            assert got.status == "optimal" and got.selected == ref.selected
            assert got.objective == pytest.approx(best, rel=1e-12) and got.bound == pytest.approx(ref.bound, rel=1e-9)


@pytest.mark.parametrize("engine", ["exact", "mip"])
def test_min_angle_team_reads_the_pattern(engine, monkeypatch) -> None:
    """A team (two models, a budget) with a minimum angle: the same optimum from bits, without floats."""
    dense, w, pos, pts = _case(3)
    n = dense.shape[1]
    team = TeamConstraints(model=np.arange(n) % 2, model_names=("wide", "tele"), model_min=(1, 1),
                           model_max=(None, None), cost=np.where(np.arange(n) % 2, 3.0, 1.0), budget=7.0)
    opts = SolveOptions(mode="multiview", k=3, views=2, min_angle_deg=25.0, engine=engine, team=team)
    ref = solve(sp.csr_matrix(dense), w, positions=pos, points=pts, options=opts)
    assert ref.status == "optimal" and ref.stats["engine_choice"]["route"] == "team"
    for mat in (sp.csr_matrix(dense).astype(bool), bits_from_csr(sp.csr_matrix(dense))):
        with monkeypatch.context() as mp:
            _no_floats(mp)
            got = solve(mat, w, positions=pos, points=pts, options=opts)
        assert (got.status, got.selected) == (ref.status, ref.selected)
        assert got.objective == pytest.approx(ref.objective, rel=1e-12)


def test_min_angle_general_estimate_counts_no_float_values() -> None:
    """The guard's figure for the general model with a minimum angle on bits: the bool pattern
    (5 bytes a pair), its row pointers and the model of every row: no float values (4 bytes a pair)."""
    from camplace.solver.engines.mip.linear import model_bytes
    from camplace.solver.engines.mip.mode_models import cover_model_size

    m, n, nnz = 2_000, 400, 300_000
    o = SolveOptions(mode="multiview", k=3, views=2, min_angle_deg=20.0, engine="mip")
    model = model_bytes("mip", *cover_model_size(m, n, nnz, 0, 0))
    assert bits_solve_bytes(m, n, o, nnz) == 5 * nnz + 8 * (m + 1) + model
