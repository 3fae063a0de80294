"""The CSV writer of points.csv and candidates.csv (camplace._io.csv_text) against a per-value
formatting oracle, and its files read back to the same arrays."""

from __future__ import annotations

import numpy as np
import pytest

from camplace._io import csv_text
from camplace.sampling.candidates import CandidateSet
from camplace.visibility.points import TargetPoints


def _oracle(header: str, rows: list[list]) -> str:
    out = header + "\n"
    for row in rows:
        out += ",".join(repr(float(v)) if isinstance(v, (float, np.floating)) else str(int(v)) for v in row) + "\n"
    return out


def test_csv_text_equals_per_value_repr() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=50) * 10.0 ** rng.integers(-12, 12, size=50)
    a[:4] = [0.1, -0.0, 1e-300, 123456789.125]
    b = rng.normal(size=50).astype(np.float32)
    i = rng.integers(-5, 1000, size=50)
    got = csv_text("a,b,i", [a, b, i])
    assert got == _oracle("a,b,i", [[x, float(y), z] for x, y, z in zip(a, b, i, strict=True)])
    assert csv_text("h", [np.zeros(0), np.zeros(0, dtype=np.int64)]) == "h\n"
    with pytest.raises(ValueError):
        csv_text("h", [np.zeros(2), np.zeros(3)])


def test_csv_text_of_repeated_values_equals_per_value_repr() -> None:
    """Long columns of few distinct values (formatted through their distinct values) give the same
    text as formatting every value: -0.0 and 0.0 apart, NaN and infinities, float32, integers,
    and a column just over and one just under the share of distinct values that takes that path."""
    from camplace import _io

    rng = np.random.default_rng(4)
    n = 2 * _io._REPEAT_MIN
    pool = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 0.1, 1e-300, -5e300, 1 / 3])
    a = pool[rng.integers(0, pool.size, size=n)]
    b = rng.normal(size=n // 4).astype(np.float32)[rng.integers(0, n // 4, size=n)]
    i = rng.integers(-3, 3, size=n)
    few = rng.normal(size=n)
    few[: n // 4] = few[n // 4: n // 2]  # 75 % distinct: formatted through the distinct values
    most = rng.normal(size=n)
    most[: n // 8] = most[n // 8: n // 4]  # 87.5 % distinct: value by value
    got = csv_text("a,b,i,f,m", [a, b, i, few, most])
    assert got == _oracle("a,b,i,f,m", [list(r) for r in zip(a, b, i, few, most, strict=True)])
    assert "-0.0," in got and "\n0.0," in got and "nan," in got and "-inf," in got


def test_points_and_candidates_read_back(tmp_path) -> None:
    rng = np.random.default_rng(5)
    m = 40
    pts = TargetPoints(rng.normal(size=(m, 3)), rng.normal(size=(m, 3)), rng.integers(0, 3, size=m),
                       rng.random(m) / m)
    pts.save(tmp_path / "points.csv")
    back = TargetPoints.load(tmp_path / "points.csv")
    for name in ("positions", "normals", "frame", "weight"):
        np.testing.assert_array_equal(getattr(back, name), getattr(pts, name))
    n = 12
    from scipy.spatial.transform import Rotation

    rot = Rotation.random(n, random_state=1).as_matrix()
    cands = CandidateSet(rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rot)
    cands.save(tmp_path / "candidates.csv")
    got = CandidateSet.load(tmp_path / "candidates.csv")
    np.testing.assert_array_equal(got.positions, cands.positions)
    np.testing.assert_array_equal(got.aims, cands.aims)
    np.testing.assert_array_equal(got.rotations, cands.rotations)
