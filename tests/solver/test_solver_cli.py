"""``camplace solve`` on a run folder (matrix + points.csv + candidates.csv)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.robust.cli import register as register_solve  # the solve verb (robust when asked)
from camplace.solver.cli import register
from tests.solver._oracle import brute_force_mode, mode_objective


def _folder(tmp_path, rng):
    m, n = 12, 7
    dense = (rng.random((m, n)) < 0.4) * rng.uniform(0.1, 1.0, (m, n))
    dense = dense.astype(np.float32).astype(np.float64)  # matrices are float32 on disk and when read back
    w = rng.uniform(0.0, 1.0, m)
    pos = rng.normal(size=(n, 3)) * 3
    pts = rng.normal(size=(m, 3))
    sp.save_npz(tmp_path / "visibility.npz", sp.csr_matrix(dense.astype(np.float32)))
    with open(tmp_path / "points.csv", "w") as fh:
        fh.write("index,x,y,z,nx,ny,nz,frame,weight\n")
        for i in range(m):
            fh.write(f"{i},{float(pts[i,0])!r},{float(pts[i,1])!r},{float(pts[i,2])!r},0,0,1,0,{float(w[i])!r}\n")
    with open(tmp_path / "candidates.csv", "w") as fh:
        fh.write("index,x,y,z,ax,ay,az\n")
        for j in range(n):
            fh.write(f"{j},{float(pos[j,0])!r},{float(pos[j,1])!r},{float(pos[j,2])!r},0,0,0\n")
    return dense, w, pos, pts


def _run(argv):
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="verb")
    handlers = {**register_solve(sub, lambda p: None), **register(sub, lambda p: None)}
    args = ap.parse_args(argv)
    return handlers[args.verb](args)


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
def test_solve_verb_matches_enumeration(tmp_path, mode, capsys) -> None:
    dense, w, pos, pts = _folder(tmp_path, np.random.default_rng(7))
    out = tmp_path / "sol.json"
    argv = ["solve", str(tmp_path), "--mode", mode, "--k", "2", "--fixed", "0", "--forbidden", "3,4", "-o", str(out)]
    angle = None
    if mode == "multiview":
        argv += ["--min-angle", "25"]
        angle = 25.0
    assert _run(argv) == 0
    sol = json.loads(out.read_text())
    best = brute_force_mode(dense, w, 2, mode, min_angle_deg=angle, pos=pos, pts=pts, fixed=(0,), forbidden=(3, 4))
    assert sol["status"] == "optimal"
    assert 0 in sol["selected"] and not {3, 4} & set(sol["selected"])
    assert sol["objective"] == pytest.approx(best, abs=1e-9)
    assert mode_objective(dense, w, tuple(sol["selected"]), mode, min_angle_deg=angle, pos=pos, pts=pts) == pytest.approx(best, abs=1e-9)


def test_solve_verb_errors(tmp_path) -> None:
    _folder(tmp_path, np.random.default_rng(1))
    with pytest.raises(CamplaceError):
        _run(["solve", str(tmp_path), "--k", "2", "--fixed", "a", "-o", str(tmp_path / "s.json")])
    with pytest.raises(CamplaceError):
        _run(["solve", str(tmp_path / "missing.npz"), "--k", "2", "-o", str(tmp_path / "s.json")])
    with pytest.raises(CamplaceError):
        _run(["solve", str(tmp_path), "-o", str(tmp_path / "s.json")])


def test_solve_keeps_to_the_runs_time_limit_unless_given(tmp_path) -> None:
    """On a run folder, ``solve`` without ``--time-limit`` keeps to the run's (solution.json's
    options), as ``camplace run`` did; ``--time-limit`` overrides it; a folder without a
    solution.json has none."""
    _folder(tmp_path, np.random.default_rng(3))
    out = tmp_path / "sol.json"
    assert _run(["solve", str(tmp_path), "--k", "2", "-o", str(out)]) == 0
    assert json.loads(out.read_text())["options"]["time_limit_s"] is None
    (tmp_path / "solution.json").write_text(json.dumps({"options": {"k": 2, "time_limit_s": 7.5}, "event_mode": "all"}))
    assert _run(["solve", str(tmp_path), "-o", str(out)]) == 0
    assert json.loads(out.read_text())["options"]["time_limit_s"] == 7.5
    assert _run(["solve", str(tmp_path), "--time-limit", "3", "-o", str(out)]) == 0
    assert json.loads(out.read_text())["options"]["time_limit_s"] == 3.0
