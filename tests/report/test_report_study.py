"""Sampler study (best objective against candidates, discrepancy) and the vision-cone density."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import qmc

from camplace.instance import builtin
from camplace.pipeline import run
from camplace.visibility.stages import stage_seeds
from camplace.report.build import percentile_of
from camplace.report.compare import load_run_data
from camplace.report.cones import ConeGrid, cone_density
from camplace.report.study import SamplerStudy, default_ladder, sampler_study
from camplace.sampling import look_at, sample_unit
from camplace.solver import coverage_weight


@pytest.fixture(scope="module")
def rd(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    run(builtin("comet-67p-bunker"), seed=6, candidates=80, points=800, sampler="sobol", outdir=out)
    return load_run_data(out)


@pytest.fixture(scope="module")
def study(rd) -> SamplerStudy:
    return sampler_study(rd, ladder=(5, 10, 20, 40, 80))


def test_default_ladder() -> None:
    assert default_ladder(2000, 3) == (25, 50, 100, 200, 500, 1000, 2000)
    assert default_ladder(150, 3) == (25, 50, 100, 150)
    assert default_ladder(30, 3) == (25, 30)


def test_best_objective_grows_with_nested_candidates(study, rd) -> None:
    for s in ("chaotic", "sobol", "uniform"):
        n, obj = study.series(s, "objective")
        assert list(n) == [5, 10, 20, 40, 80]
        rows = [r for r in study.rows if r["sampler"] == s]
        assert all(r["status"] == "optimal" for r in rows)
        # optimum over a superset of candidates is never lower
        assert np.all(np.diff(obj) >= -1e-12), (s, obj)
        assert np.all(obj <= rd.points.weight.sum() + 1e-12)
    # the run's own sampler at the run's size is the run itself
    last = [r for r in study.rows if r["sampler"] == "sobol" and r["n_positions"] == 80][0]
    assert last["source"] == "run" and last["objective"] == rd.solution.objective
    # and its smaller rungs are solved on the run's own first columns
    r20 = [r for r in study.rows if r["sampler"] == "sobol" and r["n_positions"] == 20][0]
    best = max(coverage_weight(rd.matrix[:, :20], rd.points.weight, [a, b, c])
               for a in range(20) for b in range(a + 1, 20) for c in range(b + 1, 20))
    assert r20["objective"] == pytest.approx(best, abs=1e-12)


def test_discrepancy_is_scipy_on_the_unit_samples(study, rd) -> None:
    seed = stage_seeds(6)[0]
    for s in ("chaotic", "sobol", "uniform"):
        u = np.clip(sample_unit(s, 80, 3, seed=seed), 1e-9, 1 - 1e-9)
        n, disc = study.series(s, "discrepancy")
        for ni, d in zip(n, disc):
            assert d == pytest.approx(qmc.discrepancy(u[:ni], method="CD"), rel=1e-9)
    # scrambled Sobol is more uniform than independent draws at 80 points
    assert study.series("sobol", "discrepancy")[1][-1] < study.series("uniform", "discrepancy")[1][-1]


def test_study_round_trip(study, tmp_path) -> None:
    study.save(tmp_path / "samplers.json")
    back = SamplerStudy.load(tmp_path / "samplers.json")
    assert back == study
    assert back.matches(study.fingerprint, 6, 3, (5, 10, 20, 40, 80), ("chaotic", "sobol", "uniform"))
    assert not back.matches(study.fingerprint, 6, 3, (5, 10), ("chaotic", "sobol", "uniform"))


def test_cone_density_against_a_per_cell_oracle() -> None:
    grid = ConeGrid((0.0, 0.0), (20.0, 10.0), cells=80)
    pos = np.array([[1.0, 5.0, 1.0], [19.0, 2.0, 2.0], [10.0, 9.0, 1.0]])
    aims = np.array([[10.0, 5.0, 1.5], [10.0, 5.0, 0.0], [10.0, 9.0, 10.0]])  # last one looks straight up
    aims[2] = pos[2] + np.array([0.0, 0.0, 5.0])
    R = look_at(pos, aims)
    fov, rng_m = math.radians(60.0), 12.0
    got = cone_density(pos, R, fov, rng_m, grid)
    assert got.shape == (len(grid.y), len(grid.x))
    want = np.zeros_like(got)
    for iy, y in enumerate(grid.y):
        for ix, x in enumerate(grid.x):
            for p, a in zip(pos[:2], aims[:2]):
                heading = math.atan2(a[1] - p[1], a[0] - p[0])
                ang = math.atan2(y - p[1], x - p[0])
                diff = abs((ang - heading + math.pi) % (2 * math.pi) - math.pi)
                if math.hypot(x - p[0], y - p[1]) <= rng_m and diff <= fov / 2:
                    want[iy, ix] += 1
    np.testing.assert_array_equal(got, want)
    assert got.max() == 2  # the two wedges overlap near the aim; the upward camera adds nothing


def test_percentile_of() -> None:
    v = np.array([0.1, 0.2, 0.3, 0.4])
    assert percentile_of(v, 0.4) == 100.0
    assert percentile_of(v, 0.25) == 50.0
    assert percentile_of(v, 0.0) == 0.0


def test_report_reuses_a_matching_study(rd, study, monkeypatch) -> None:
    import camplace.report.study as study_mod
    from camplace.report.build import _load_or_run_study

    study.save(rd.outdir / "samplers.json")
    kw = dict(samplers=("chaotic", "sobol", "uniform"), ladder=(5, 10, 20, 40, 80), time_limit_s=None, cache=True, reporter=None)

    def boom(*a, **k):
        raise AssertionError("the study was recomputed")

    monkeypatch.setattr(study_mod, "sampler_study", boom)
    assert _load_or_run_study(rd, **kw) == study
    with pytest.raises(AssertionError, match="recomputed"):
        _load_or_run_study(rd, **{**kw, "ladder": (5, 80)})
