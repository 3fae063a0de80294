"""Campaigns: deterministic per seed, scored with the solver's objective on a run's rows, files round-trip."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.cli
from camplace.errors import CamplaceError
from camplace.instance import builtin
from camplace.event import event_aims
from camplace.pipeline import run
from camplace.visibility.stages import compute_points
from camplace.report.campaign import CAMPAIGN_COLUMNS, Campaign, problem_fingerprint, run_campaign, score_systems
from camplace.report.compare import load_run_data
from camplace.report.legacy import legacy_camera_scores, legacy_target
from camplace.sampling import sample_positions
from camplace.visibility.store import load_visibility

SEED, POINTS = 3, 1500


@pytest.fixture
def cli(monkeypatch):
    monkeypatch.setattr(camplace.cli, "VERB_MODULES", ("camplace.validation.cli", "camplace.report.cli"))
    return camplace.cli.main


@pytest.fixture(scope="module")
def inst():
    return builtin("comet-67p-bunker")


@pytest.fixture(scope="module")
def camp(inst, tmp_path_factory) -> tuple[Campaign, Path]:
    out = tmp_path_factory.mktemp("camp") / "campaign-uniform"
    return run_campaign(inst, systems=25, sampler="uniform", seed=SEED, points=POINTS, outdir=out), out


def dense_coverage(matrix, weights: np.ndarray, cols) -> float:
    """Oracle: weight of the rows with a positive entry in any of the columns (dense numpy)."""
    A = np.asarray(sp.csr_matrix(matrix)[:, list(cols)].todense())
    return float(weights[(A > 0).any(axis=1)].sum())


def test_campaign_is_deterministic_per_seed(inst, camp, tmp_path) -> None:
    c1, out1 = camp
    out2 = tmp_path / "again"
    c2 = run_campaign(inst, systems=25, sampler="uniform", seed=SEED, points=POINTS, outdir=out2)
    for name in ("campaign.csv", "cameras.csv"):
        assert (out1 / name).read_bytes() == (out2 / name).read_bytes(), name
    assert (load_visibility(out1) != load_visibility(out2)).nnz == 0
    np.testing.assert_array_equal(c1.objective, c2.objective)
    c3 = run_campaign(inst, systems=25, sampler="uniform", seed=SEED + 1, points=POINTS)
    assert not np.array_equal(c1.positions, c3.positions)


def test_samplers_differ_and_positions_are_in_the_volume_aimed_at_the_event(inst) -> None:
    lo, hi = np.array(inst.volume.min_m), np.array(inst.volume.max_m)
    aim = event_aims(inst, 1)[0]
    got = {}
    for s in ("chaotic", "uniform", "sobol"):
        c = run_campaign(inst, systems=10, sampler=s, seed=SEED, points=300)
        p = c.positions.reshape(-1, 3)
        assert np.all(p > lo) and np.all(p < hi)
        np.testing.assert_allclose(c.aims.reshape(-1, 3), np.broadcast_to(aim, p.shape))
        fwd = c.rotations.reshape(-1, 3, 3)[:, :, 2]
        want = (aim - p) / np.linalg.norm(aim - p, axis=1, keepdims=True)
        np.testing.assert_allclose(fwd, want, atol=1e-12)
        got[s] = p
    assert not np.allclose(got["chaotic"], got["uniform"]) and not np.allclose(got["sobol"], got["uniform"])


def test_positions_come_from_their_own_seed_stream(inst, camp) -> None:
    c, _ = camp
    pos_seed = np.random.SeedSequence(SEED).spawn(3)[2].spawn(2)[0]
    want = sample_positions("uniform", 25 * 3, inst.volume.min_m, inst.volume.max_m, seed=pos_seed)
    np.testing.assert_array_equal(c.positions.reshape(-1, 3), want)


def test_objective_is_the_solver_objective_on_the_run_rows(inst, camp, tmp_path) -> None:
    c, out = camp
    pts = compute_points(inst, POINTS, SEED)
    A = load_visibility(out)
    assert A.shape == (POINTS, 25 * 3)
    for s in range(c.n_systems):
        assert c.objective[s] == pytest.approx(dense_coverage(A, pts.weight, range(3 * s, 3 * s + 3)), abs=1e-12)
        for j in range(3):
            assert c.camera_objective[s, j] == pytest.approx(dense_coverage(A, pts.weight, [3 * s + j]), abs=1e-12)
    # a run with the same seed and points (read back from its folder) has the same rows and scene
    r = run(inst, seed=SEED, points=POINTS, candidates=40, outdir=tmp_path / "run")
    rd = load_run_data(tmp_path / "run")
    assert r.n_points == POINTS and rd.fingerprint == c.fingerprint
    np.testing.assert_array_equal(rd.points.weight, pts.weight)
    assert problem_fingerprint(inst, compute_points(inst, POINTS, SEED + 1)) != c.fingerprint


def test_score_systems_matches_a_brute_force_oracle() -> None:
    rng = np.random.default_rng(0)
    A = sp.csr_matrix((rng.random((60, 12)) < 0.2) * rng.random((60, 12)))
    w = rng.random(60)
    cols = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 11], [2, 9, 10]])
    got = score_systems(A, w, cols)
    np.testing.assert_allclose(got, [dense_coverage(A, w, c) for c in cols], rtol=1e-9, atol=0)  # sums up to ~30


def test_legacy_columns_are_algorithm_2(inst, camp) -> None:
    c, _ = camp
    s = legacy_camera_scores(c.positions, legacy_target(inst))
    np.testing.assert_array_equal(c.legacy_camera_score, s["delta"])
    np.testing.assert_array_equal(c.legacy_distance_m, s["distance"])
    np.testing.assert_array_equal(c.legacy_area, s["area"])
    np.testing.assert_allclose(c.legacy_score, s["delta"].sum(axis=1), rtol=1e-15)


def test_files_round_trip(camp) -> None:
    c, out = camp
    rows = list(csv.DictReader((out / "campaign.csv").read_text().splitlines()))
    assert tuple(rows[0].keys()) == CAMPAIGN_COLUMNS
    assert len(rows) == 25 * 3
    assert [(int(r["system"]), int(r["camera"])) for r in rows[:4]] == [(1, 1), (1, 2), (1, 3), (2, 1)]
    meta = json.loads((out / "campaign.json").read_text())
    assert meta["n_systems"] == 25 and meta["k"] == 3 and meta["sampler"] == "uniform" and meta["seed"] == SEED
    assert meta["summary"]["objective"]["max"] == pytest.approx(float(c.objective.max()))
    back = Campaign.load(out, matrix=True)
    for name in ("positions", "aims", "rotations", "objective", "camera_objective", "legacy_score", "legacy_camera_score"):
        np.testing.assert_array_equal(getattr(back, name), getattr(c, name), err_msg=name)
    assert back.legacy == c.legacy and back.fingerprint == c.fingerprint and back.name == "campaign-uniform"
    assert (back.matrix != c.matrix).nnz == 0


def test_campaign_verb(cli, tmp_path, capsys) -> None:
    out = tmp_path / "c"
    assert cli(["campaign", "comet-67p-bunker", "--systems", "6", "--sampler", "sobol", "--seed", "2", "--points", "300", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "6 random 3-camera systems (sobol, seed 2)" in text
    c = Campaign.load(out)
    assert c.n_systems == 6 and c.sampler == "sobol" and c.n_points == 300


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--systems", "0"], "--systems"),
        (["--systems", "3", "--seed", "-1"], "--seed"),
        (["--systems", "3", "--k", "0"], "--k"),
        (["--systems", "3", "--points", "0"], "--points"),
    ],
)
def test_campaign_verb_errors(cli, tmp_path, capsys, args, needle) -> None:
    assert cli(["campaign", "comet-67p-bunker", *args, "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and needle in err and "\n" not in err


def test_load_errors_name_the_file(tmp_path) -> None:
    with pytest.raises(CamplaceError, match="campaign.json"):
        Campaign.load(tmp_path)
    (tmp_path / "campaign.json").write_text("{}")
    with pytest.raises(CamplaceError, match="not a camplace campaign"):
        Campaign.load(tmp_path)
