"""Samplers: uniform in distribution, inside the volume, deterministic per seed."""

import numpy as np
import pytest
from scipy import stats

from camplace.errors import CamplaceError
from camplace.sampling import SAMPLERS, look_at, make_candidates, sample_positions, sample_unit
from camplace.sampling.samplers import logistic_orbits


@pytest.mark.parametrize("kind", SAMPLERS)
def test_uniform_marginals(kind: str) -> None:
    u = sample_unit(kind, 20000, 3, seed=11)
    assert u.shape == (20000, 3)
    for axis in range(3):
        # Kolmogorov-Smirnov against U(0, 1): the density correction must make the chaotic orbit uniform
        assert stats.kstest(u[:, axis], "uniform").pvalue > 1e-3


def test_raw_logistic_orbit_is_not_uniform_but_corrected_is() -> None:
    """Oracle: the uncorrected r=4 orbit follows the arcsine law, so the correction is needed."""
    x = np.random.default_rng(0).uniform(0.05, 0.95, 1)
    corrected = logistic_orbits(x, 20000)[:, 0]
    raw = np.sin(corrected * np.pi / 2) ** 2  # undo the correction
    assert stats.kstest(raw, "uniform").pvalue < 1e-6
    assert stats.kstest(raw, stats.arcsine.cdf).pvalue > 1e-3
    assert stats.kstest(corrected, "uniform").pvalue > 1e-3


def test_chaotic_axes_and_lags_uncorrelated() -> None:
    u = sample_unit("chaotic", 20000, 3, seed=2)
    c = np.corrcoef(u.T)
    assert np.all(np.abs(c[np.triu_indices(3, 1)]) < 0.03)
    for lag in (1, 2, 3):
        assert abs(np.corrcoef(u[:-lag, 0], u[lag:, 0])[0, 1]) < 0.03


@pytest.mark.parametrize("kind", SAMPLERS)
def test_seeded_and_inside(kind: str) -> None:
    lo, hi = (0.3, 0.3, 0.3), (29.7, 2.7, 2.7)
    a = sample_positions(kind, 500, lo, hi, seed=5)
    b = sample_positions(kind, 500, lo, hi, seed=5)
    c = sample_positions(kind, 500, lo, hi, seed=6)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(a > np.array(lo)) and np.all(a < np.array(hi))


def test_unknown_sampler() -> None:
    with pytest.raises(CamplaceError, match="unknown sampler"):
        sample_unit("halton", 10)


def test_look_at_opencv_convention() -> None:
    rng = np.random.default_rng(1)
    pos = rng.uniform(-5, 5, (200, 3))
    aim = rng.uniform(-1, 1, (200, 3))
    R = look_at(pos, aim)
    # orthonormal, right-handed
    assert np.allclose(np.einsum("nji,njk->nik", R, R), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    # the aim point lies on the optical axis (+z) in front of the camera
    cam = np.einsum("nk,nkl->nl", aim - pos, R)
    assert np.allclose(cam[:, :2], 0, atol=1e-9) and np.all(cam[:, 2] > 0)
    # world up (+z) points to image up, i.e. negative camera y (y is down)
    up_cam = np.einsum("k,nkl->nl", np.array([0, 0, 1.0]), R)
    assert np.all(up_cam[:, 1] < 0)


def test_look_at_straight_down() -> None:
    R = look_at(np.array([[0, 0, 5.0]]), np.zeros((1, 3)))
    assert np.allclose(R[0] @ np.array([0, 0, 1.0]), [0, 0, -1])
    assert np.allclose(R[0].T @ R[0], np.eye(3))


def test_candidates_csv_roundtrip(tmp_path) -> None:
    from camplace.sampling import CandidateSet

    c = make_candidates("sobol", 50, (0, 0, 0), (3, 2, 1), np.array([1.5, 1.0, 0.5]), seed=3)
    c.save(tmp_path / "candidates.csv")
    d = CandidateSet.load(tmp_path / "candidates.csv")
    assert np.array_equal(c.positions, d.positions) and np.array_equal(c.rotations, d.rotations)
    (tmp_path / "bad.csv").write_text("x,y\n1,2\n")
    with pytest.raises(CamplaceError, match="header"):
        CandidateSet.load(tmp_path / "bad.csv")


def _orbits_numpy(x0, n, burn_in=1000, stride=7, r=4.0):
    """The chaotic sampler as first written (numpy, elementwise): the compiled one's oracle."""
    x = np.array(x0, dtype=np.float64)
    out = np.empty((n, x.size), dtype=np.float64)
    for _ in range(burn_in):
        x = r * x * (1.0 - x)
    for i in range(n):
        for _ in range(stride):
            x = r * x * (1.0 - x)
            bad = (x <= 1e-12) | (x >= 1.0 - 1e-12)
            if bad.any():
                x[bad] = np.mod(x[bad] + 0.6180339887498949 + 1e-3 * (i + 1), 1.0) * 0.98 + 0.01
        out[i] = x
    return (2.0 / np.pi) * np.arcsin(np.sqrt(out))


def test_compiled_orbits_are_the_numpy_orbits_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    for x0 in (rng.uniform(0.05, 0.95, 3), rng.uniform(0.05, 0.95, 6), np.array([0.5, 0.25, 0.75])):
        got = logistic_orbits(x0, 3000)
        want = _orbits_numpy(x0, 3000)
        assert got.tobytes() == want.tobytes()
    # an orbit that hits the fixed point: x = 0.5 -> 1 -> 0, nudged the same way
    assert logistic_orbits(np.array([0.5]), 50, burn_in=0).tobytes() == _orbits_numpy([0.5], 50, burn_in=0).tobytes()
