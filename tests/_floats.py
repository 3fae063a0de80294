"""Comparisons of floating-point values that were computed by different code paths.

Two sums of the same float64 numbers taken in a different order (engine vs enumeration oracle,
numba loop vs BLAS dot, pairwise ``np.sum`` vs a Python loop, a SIMD path vs another on another
CPU, another thread count) differ by a few units in the last place times the number of terms, e.g.
``20.18421341662564`` vs ``20.184213416625642``. Such values are compared with a tolerance
relative to their size: an absolute ``1e-12`` is 9 ulps at 1000 and less than one ulp above 8192, and
``a - 1e-12 >= b - 1e-12`` is just ``a >= b``.

:data:`REL` covers float64 sums of up to about 1e6 non-negative terms (worst-case relative error
``n * 2**-53 ~ 1e-10``, typical far less). Exact contracts (integer counts, selected indices, values
read back from a file, same seed same output, ``bound == objective`` when the code sets one to the
other) are still compared exactly.
"""

from __future__ import annotations

REL = 1e-9  # float64 sums computed in different orders


def _tol(a: float, b: float, rel_tol: float, abs_tol: float, scale: float) -> float:
    return rel_tol * max(abs(a), abs(b), abs(scale)) + abs_tol


def assert_le(a: float, b: float, *, rel_tol: float = REL, abs_tol: float = 0.0, scale: float = 0.0,
              what: str = "") -> None:
    """Assert ``a <= b`` up to rounding: ``a <= b + rel_tol * max(|a|, |b|, |scale|) + abs_tol``.

    Parameters
    ----------
    a, b : float
        The two values (e.g. a lower value and a bound on it).
    rel_tol : float
        Relative tolerance (default :data:`REL`).
    abs_tol : float
        Absolute floor, for values that may both be (near) zero after cancellation.
    scale : float
        Magnitude of the terms when the values are differences of larger sums (e.g. ``w.sum()``).
    what : str
        Label printed with both values on failure.
    """
    a, b = float(a), float(b)
    tol = _tol(a, b, rel_tol, abs_tol, scale)
    assert a <= b + tol, f"{what + ': ' if what else ''}{a!r} > {b!r} by {a - b:.3g} (tolerance {tol:.3g})"


def assert_ge(a: float, b: float, *, rel_tol: float = REL, abs_tol: float = 0.0, scale: float = 0.0,
              what: str = "") -> None:
    """Assert ``a >= b`` up to rounding (see :func:`assert_le`)."""
    a, b = float(a), float(b)
    tol = _tol(a, b, rel_tol, abs_tol, scale)
    assert a >= b - tol, f"{what + ': ' if what else ''}{a!r} < {b!r} by {b - a:.3g} (tolerance {tol:.3g})"

