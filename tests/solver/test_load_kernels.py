"""The solver's kernels loaded while the visibility is cast (issue 29): the warm-up loads every
kernel a bit solve then calls, never changes a result, and the visibility stage runs it once."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from camplace.solver.bits_route import load_kernels
from camplace.solver.options import SolveOptions

_PROBE = r"""
import json, sys
import numpy as np
from numba.core.registry import CPUDispatcher

def loaded():
    out = set()
    for name, mod in list(sys.modules.items()):
        if name.startswith("camplace"):
            for attr, v in list(vars(mod).items()):
                if isinstance(v, CPUDispatcher):
                    out.update(f"{name}:{attr}{sig}" for sig in v.overloads)
    return out

from camplace.solver import solve
from camplace.solver.bits_route import load_kernels
from camplace.solver.options import SolveOptions
from camplace.visibility.bits import BitMatrix

k = int(sys.argv[1])
warm = sys.argv[2] == "warm"
if warm:
    assert load_kernels(SolveOptions(mode="maxcover", k=k))
before = loaded()
rng = np.random.default_rng(7)
m, n = (2000, 240) if k < 4 else (1000, 90)  # a few seconds each
# clustered columns: many dominated, many identical rows, a search that branches
base = rng.random((m, 12)) < 0.35
cols = np.concatenate([base[:, rng.integers(0, 12, n)] & (rng.random((m, n)) < 0.8)], axis=1)
pad = np.zeros((n, -(-m // 64) * 64), dtype=bool)
pad[:, :m] = cols.T
words = np.packbits(pad, axis=1, bitorder="little").view(np.uint64)
res = solve(BitMatrix(words, m), rng.random(m), k)
print(json.dumps({"new": sorted(loaded() - before), "before": len(before), "status": res.status,
                  "selected": list(res.selected), "objective": res.objective}))
"""


def _probe(k: int, warm: bool) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE, str(k), "warm" if warm else "cold"], capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("k", [2, 3, 4])
def test_a_bit_solve_after_the_warm_up_loads_no_kernel(k: int) -> None:
    cold, warm = _probe(k, False), _probe(k, True)
    assert cold["before"] == 0 and len(cold["new"]) >= 5  # a fresh process: the solve loads its kernels
    assert warm["before"] >= len(cold["new"]) and warm["new"] == []  # ... all of them loaded beforehand
    assert (warm["status"], warm["selected"], warm["objective"]) == (cold["status"], cold["selected"],
                                                                      cold["objective"])


@pytest.mark.parametrize("opts", [SolveOptions(mode="multiview", k=3), SolveOptions(mode="maxcover", k=6),
                                  SolveOptions(mode="maxcover", k=3, engine="mip"),
                                  SolveOptions(mode="maxcover", k=3, fixed=(1,)),
                                  SolveOptions(mode="setcover", k=None)])
def test_the_warm_up_is_only_for_the_bit_route(opts: SolveOptions) -> None:
    assert load_kernels(opts) is False


def test_the_visibility_stage_runs_the_idle_work_once_and_ignores_its_errors() -> None:
    from camplace.event import event_aims
    from camplace.instance import builtin
    from camplace.sampling import make_candidates
    from camplace.visibility import compute_visibility, make_target_points

    inst = builtin("comet-67p-bunker")
    pts = make_target_points(inst, 2000, seed=1)
    cands = make_candidates("sobol", 160, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=2)
    ref = compute_visibility(inst, cands, pts, chunk_size=16, workers=2)
    calls = []

    def idle() -> None:
        calls.append(1)
        raise RuntimeError("boom")

    got = compute_visibility(inst, cands, pts, chunk_size=16, workers=2, idle=idle)
    assert calls == [1]
    np.testing.assert_array_equal(got.bits.words, ref.bits.words)
    assert got.stats == ref.stats


def test_a_run_formats_its_csv_files_while_the_rays_are_cast(tmp_path) -> None:
    """``camplace run``'s idle work formats candidates.csv and points.csv during the cast (only
    when it writes a folder), and the folder holds the same text as a fresh format."""
    import camplace
    from camplace.instance import builtin
    from camplace.sampling import CandidateSet
    from camplace.visibility import TargetPoints, engine

    seen = []
    real = engine._while_waiting

    def spy(idle) -> None:
        real(idle)
        seen.append(idle)

    inst = builtin("comet-67p-bunker")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(engine, "_while_waiting", spy)
        sol = camplace.run(inst, candidates=600, points=1500, seed=3, cache=False, outdir=tmp_path / "run")
    assert len(seen) == 1 and "_csv" in sol.candidates.__dict__ and "_csv" in sol.visibility.points.__dict__
    fresh = CandidateSet(sol.candidates.positions, sol.candidates.aims, sol.candidates.rotations)
    assert (tmp_path / "run" / "candidates.csv").read_text() == fresh.to_csv() == sol.candidates.to_csv()
    p = sol.visibility.points
    fresh_p = TargetPoints(p.positions, p.normals, p.frame, p.weight)
    assert (tmp_path / "run" / "points.csv").read_text() == fresh_p.to_csv()
    assert "_csv" not in fresh.__dict__ or fresh.__dict__["_csv"] == fresh.to_csv()
    # without a folder to write, the cast formats nothing
    sol2 = camplace.run(inst, candidates=600, points=1500, seed=3, cache=False)
    assert "_csv" not in sol2.candidates.__dict__ and "_csv" not in sol2.visibility.points.__dict__
