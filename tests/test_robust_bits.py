"""The robust stage on column bitsets (issue 32): a binary run's scenarios are stacked as bits
(no CSR), their per-scenario values, the mean solve and the p10 solve read the bits; the answers
are the CSR stacking's (the p10 pieces against the old CSR computations: tests/test_robust_p10_bits.py).

Oracles: :func:`camplace.robust.stack_scenarios` of the wide matrix's CSR (itself checked against a
dense restack in tests/test_robust.py), the CSR route's solve, enumeration of every k-subset."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.robust.stage as stage
from camplace.instance import RobustSpec, resolve_instance
from camplace.robust import scenario_matrix, solve_robust, stack_scenarios
from camplace.robust.p10 import scenario_values
from camplace.robust.stage import stack_bit_scenarios, stack_bits_bytes
from camplace.solver.options import SolveOptions
from camplace.visibility import compute_visibility
from camplace.visibility.bits import BitMatrix, bit_words, bits_from_csr
from camplace.visibility.stages import compute_points, make_run_candidates, stage_seeds


def _no_csr(mp) -> None:
    def refuse(self, *args, **kwargs):
        raise AssertionError("a CSR of the bits was made")

    mp.setattr(BitMatrix, "tocsr", refuse)


def _wide(rng, m: int, n: int, s: int, dens: float) -> sp.csr_matrix:
    return sp.csr_matrix((rng.random((m, n * s)) < dens).astype(np.float32))


@pytest.mark.parametrize("m, n, s", [(1, 1, 1), (5, 3, 4), (64, 7, 3), (63, 4, 5), (130, 9, 2), (200, 3, 7), (70, 0, 3)])
def test_stack_bit_scenarios_is_the_csr_stacking(m: int, n: int, s: int, monkeypatch) -> None:
    """Row counts on and off word boundaries, several column blocks (a tiny block size): the
    stacked bits are those of the CSR stacking, bit for bit, padding rows empty."""
    rng = np.random.default_rng(m + 10 * n + 100 * s)
    wide = _wide(rng, m, n, s, 0.3)
    ref = bits_from_csr(stack_scenarios(wide, n, s))
    for block in (stage._STACK_BLOCK_BYTES, 1, 3 * s * m):
        monkeypatch.setattr(stage, "_STACK_BLOCK_BYTES", block)
        got = stack_bit_scenarios(bits_from_csr(wide), n, s)
        assert got.shape == (s * m, n)
        assert got.words.shape == (n, bit_words(s * m))
        np.testing.assert_array_equal(got.words, ref.words)


def test_stack_bit_scenarios_checks_the_width() -> None:
    from camplace.errors import CamplaceError

    with pytest.raises(CamplaceError, match="expected 3 x 2"):
        stack_bit_scenarios(bits_from_csr(sp.csr_matrix(np.ones((4, 5), dtype=np.float32))), 2, 3)


def test_stack_bits_bytes_counts_both_layouts() -> None:
    m, n, s = 1000, 50, 8
    assert stack_bits_bytes(m, n, s) == 8 * (n * s * bit_words(m) + n * bit_words(s * m)) + 2 * stage._STACK_BLOCK_BYTES


@pytest.mark.parametrize("mode, views", [("maxcover", 2), ("quality", 2), ("multiview", 2), ("multiview", 3)])
def test_scenario_values_on_bits_equal_csr(mode: str, views: int, monkeypatch) -> None:
    rng = np.random.default_rng(7)
    m, n, s = 97, 8, 5
    stacked = stack_scenarios(_wide(rng, m, n, s, 0.35), n, s)
    bits = bits_from_csr(stacked)
    w = np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
    with monkeypatch.context() as mp:
        _no_csr(mp)
        for sel in [(), (3,), (0, 5), (1, 2, 7), (7, 2, 2), tuple(range(n))]:
            got = scenario_values(bits, w, s, sel, mode=mode, views=views)
            ref = scenario_values(stacked, w, s, sel, mode=mode, views=views)
            assert got.tobytes() == ref.tobytes()
    with pytest.raises(Exception, match="out of range"):
        scenario_values(bits, w, s, (n,))


@pytest.fixture(scope="module")
def bunker():
    """A small bunker problem: 24 candidates x ~300 rows (binary instance)."""
    inst = resolve_instance("comet-67p-bunker")
    cand_seed, _ = stage_seeds(0)
    cands = make_run_candidates(inst, "chaotic", 24, 1, cand_seed)
    pts = compute_points(inst, 300, 0)
    return inst, cands, pts


def test_scenario_matrix_of_a_binary_run_is_bits(bunker, monkeypatch) -> None:
    """With bits=True the scenario matrix comes back as bits, equal to the CSR stacking of the same casts; a
    subset of columns too; no CSR on the way."""
    inst, cands, pts = bunker
    spec = RobustSpec(position_sigma_m=0.1, rotation_sigma_deg=5.0, scenarios=4)
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = scenario_matrix(inst, cands, pts, spec, seed=3, cache=False, nominal_nnz=1, bits=True)
        sub = scenario_matrix(inst, cands, pts, spec, seed=3, cache=False, columns=[2, 5, 11], scenarios=3, bits=True)
    assert got.format == "bits" and sub.format == "bits"
    csr = scenario_matrix(inst, cands, pts, spec, seed=3, cache=False)  # without bits=True: CSR as before
    assert sp.issparse(csr) and (bits_from_csr(csr).words == got.words).all()
    from camplace.sampling.perturb import IN_SAMPLE_STREAM, perturb_poses

    for mat, cols, s in ((got, None, 4), (sub, [2, 5, 11], 3)):
        poses = perturb_poses(cands, cols, s, 0.1, 5.0, seed=3, stream=IN_SAMPLE_STREAM, design="sobol")
        wide = compute_visibility(inst, poses, pts, layout="csr").matrix
        ref = stack_scenarios(wide, len(cands) if cols is None else len(cols), s)
        np.testing.assert_array_equal(mat.words, bits_from_csr(ref).words)


def test_scenario_matrix_checks_the_bits_against_the_budget(bunker) -> None:
    from camplace.errors import CamplaceError

    inst, cands, pts = bunker
    spec = RobustSpec(position_sigma_m=0.1, rotation_sigma_deg=5.0, scenarios=4)
    need = stack_bits_bytes(len(pts), len(cands), 4)
    with pytest.raises(CamplaceError, match="--scenarios"):
        scenario_matrix(inst, cands, pts, spec, seed=3, cache=False, nominal_nnz=1, memory_budget_bytes=need - 1,
                        bits=True)


def _enumerate_mean(stacked, w, s, k, mode, views):
    n = stacked.shape[1]
    return max(float(np.mean(scenario_values(stacked, w, s, c, mode=mode, views=views)))
               for c in itertools.combinations(range(n), k))


@pytest.mark.parametrize("mode, k, extra", [("maxcover", 2, {}), ("maxcover", 3, {"fixed": (4,)}),
                                            ("multiview", 3, {}), ("multiview", 2, {"forbidden": (0, 6)})])
def test_mean_solve_on_bits_equals_csr_and_enumeration(mode: str, k: int, extra, monkeypatch) -> None:
    rng = np.random.default_rng(k)
    m, n, s = 83, 10, 4
    stacked = stack_scenarios(_wide(rng, m, n, s, 0.25), n, s)
    bits = bits_from_csr(stacked)
    w = np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
    spec = RobustSpec(position_sigma_m=0.1, rotation_sigma_deg=5.0, scenarios=s)
    opts = SolveOptions(mode=mode, k=k, views=2, **extra)
    ref = solve_robust(stacked, w, spec, opts)
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = solve_robust(bits, w, spec, opts)
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)
    assert got.status == "optimal"
    if not extra:
        assert got.objective == pytest.approx(_enumerate_mean(stacked, w, s, k, mode, 2), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("mode", ["maxcover", "multiview"])
def test_p10_on_bits_equals_csr(mode: str, monkeypatch) -> None:
    """p10 on bits, no CSR of them made: the same answer as from the float32 CSR."""
    rng = np.random.default_rng(11)
    m, n, s = 40, 7, 5
    stacked = stack_scenarios(_wide(rng, m, n, s, 0.3), n, s)
    w = rng.random(m)
    spec = RobustSpec(position_sigma_m=0.1, rotation_sigma_deg=5.0, scenarios=s, objective="p10")
    opts = SolveOptions(mode=mode, k=2, views=2)
    ref = solve_robust(stacked, w, spec, opts)
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = solve_robust(bits_from_csr(stacked), w, spec, opts)
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)
    assert got.stats["model_nonzeros"] == ref.stats["model_nonzeros"]


def test_robust_run_and_solve_verb_read_bits(tmp_path, monkeypatch) -> None:
    """A binary instance's robust run and the ``solve --pose-error`` verb on its folder: the
    nominal and mean solves, the scenarios and their values on bits (tocsr refused), the verb's
    answer the run's."""
    import json

    import camplace
    from camplace.cli import main

    _no_csr(monkeypatch)
    out = tmp_path / "run"
    from camplace.robust import make_spec

    sol = camplace.run("comet-67p-bunker", candidates=30, points=300, k=2, cache=False,
                       robust=make_spec(None, "0.1,5", 4), outdir=out)
    m = json.loads((out / "solution.json").read_text())["n_points"]
    assert sol.robust["stacked_shape"] == [4 * m, 30]
    assert main(["solve", str(out), "--pose-error", "0.1,5", "--scenarios", "4", "-o", str(tmp_path / "s.json")]) == 0
    again = json.loads((tmp_path / "s.json").read_text())
    assert again["selected"] == list(sol.selected)
    assert again["objective"] == pytest.approx(sol.objective, rel=1e-9)
