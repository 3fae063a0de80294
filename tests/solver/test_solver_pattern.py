"""The solver on a bool pattern (``load_visibility(..., pattern=True)`` of a binary matrix): no float
copy, and the same answer as on the float32 matrix, which matches enumeration."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.robust.cli import register
from camplace.solver import solve
from camplace.solver.cli import load_problem
from camplace.solver.problem.checks import values_matrix
from camplace.visibility import store
from tests.solver._oracle import brute_force_mode


def _instance(seed: int, m: int = 40, n: int = 9, density: float = 0.3):
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n)) < density).astype(np.float32)
    w = rng.uniform(0.0, 1.0, m)
    pos = rng.normal(size=(n, 3)) * 3
    pts = rng.normal(size=(m, 3))
    flt = sp.csr_matrix(dense)
    pat = sp.csr_matrix((np.ones(flt.nnz, dtype=np.bool_), flt.indices, flt.indptr), shape=flt.shape)
    pat.has_canonical_format = True
    return dense, w, pos, pts, flt, pat


def test_a_bool_pattern_is_taken_without_a_copy() -> None:
    *_, flt, pat = _instance(0)
    assert values_matrix(pat) is pat
    assert values_matrix(flt) is flt


CASES = {
    "maxcover k=2": dict(k=2),
    "maxcover k=3 fixed/forbidden": dict(k=3, fixed=(1,), forbidden=(4, 5)),
    "maxcover large-k k=5": dict(k=5),
    "maxcover mip": dict(k=2, engine="mip"),
    "multiview k=3": dict(k=3, mode="multiview", views=2),
    "multiview k=4 views=3": dict(k=4, mode="multiview", views=3),
    "multiview k=3 fixed": dict(k=3, mode="multiview", views=2, fixed=(0,)),
    "multiview min-angle": dict(k=3, mode="multiview", views=2, min_angle_deg=25.0),
    "quality k=2": dict(k=2, mode="quality"),
    "min-distance": dict(k=2, min_distance_m=2.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_pattern_and_float_solve_alike_and_match_enumeration(case) -> None:
    dense, w, pos, pts, flt, pat = _instance(11)
    kw = dict(CASES[case])
    if kw.get("min_angle_deg") is not None or kw.get("min_distance_m") is not None:
        kw.update(positions=pos, points=pts if kw.get("min_angle_deg") is not None else None)
    a = solve(pat, w, **kw)
    b = solve(flt, w, **kw)
    assert (a.selected, a.status, a.objective, a.bound) == (b.selected, b.status, b.objective, b.bound)
    best = brute_force_mode(dense, w, kw["k"], kw.get("mode", "maxcover"), views=kw.get("views", 2),
                            min_angle_deg=kw.get("min_angle_deg"), pos=pos, pts=pts, fixed=kw.get("fixed", ()),
                            forbidden=kw.get("forbidden", ()), dmin=kw.get("min_distance_m"))
    assert a.status == "optimal"
    assert a.objective == pytest.approx(best, rel=1e-9, abs=1e-12)


def test_pattern_and_float_set_cover_alike() -> None:
    _, w, _, _, flt, pat = _instance(12, density=0.4)
    a = solve(pat, w, mode="setcover", iterations=200)
    b = solve(flt, w, mode="setcover", iterations=200)
    assert (a.selected, a.status, a.objective, a.bound) == (b.selected, b.status, b.objective, b.bound)
    covered = (flt[:, list(a.selected)].sum(axis=1).A.ravel() > 0) | (flt.sum(axis=1).A.ravel() == 0)
    assert covered.all()


def _folder(tmp_path, dense, w):
    m, n = dense.shape
    store.save_matrix(tmp_path, sp.csr_matrix(dense))
    with open(tmp_path / "points.csv", "w") as fh:
        fh.write("index,x,y,z,nx,ny,nz,frame,weight\n")
        for i in range(m):
            fh.write(f"{i},0,0,0,0,0,1,0,{float(w[i])!r}\n")


def _run(argv):
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="verb")
    handlers = register(sub, lambda p: None)
    return handlers["solve"](ap.parse_args(argv))


@pytest.mark.parametrize("graded", [False, True])
def test_solve_verb_reads_a_binary_folder_as_its_pattern(tmp_path, graded, capsys) -> None:
    dense, w, *_ = _instance(13)
    if graded:
        dense = dense * np.random.default_rng(1).uniform(0.1, 1.0, dense.shape).astype(np.float32)
    _folder(tmp_path, dense, w)
    matrix, weights, positions, _ = load_problem(tmp_path)
    assert matrix.dtype == (np.float32 if graded else np.bool_)
    assert np.array_equal(matrix.toarray() > 0, dense > 0) and positions is None
    assert load_problem(tmp_path, pattern=False)[0].dtype == np.float32  # for quality / minimum angle
    mode = "quality" if graded else "maxcover"
    out = tmp_path / "sol.json"
    assert _run(["solve", str(tmp_path), "--mode", mode, "--k", "2", "-o", str(out)]) == 0
    sol = json.loads(out.read_text())
    assert sol["status"] == "optimal"
    assert sol["objective"] == pytest.approx(brute_force_mode(dense.astype(np.float64), w, 2, mode), rel=1e-9)


def test_values_of_a_pattern_are_estimated_before_they_are_made() -> None:
    dense, w, _, _, flt, pat = _instance(14)
    with pytest.raises(CamplaceError, match="float32 values of the matrix"):
        solve(pat, w, 2, mode="quality", memory_budget_bytes=4 * pat.nnz - 1)
    a = solve(pat, w, 2, mode="quality", memory_budget_bytes=1 << 30)
    assert a.objective == pytest.approx(brute_force_mode(dense.astype(np.float64), w, 2, "quality"), rel=1e-9)
