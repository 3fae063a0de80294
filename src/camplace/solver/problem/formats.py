"""Readers for public set-cover benchmark files (OR-Library, GECCO 2020 camera placement)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError

__all__ = ["CoverInstance", "read_orlib", "read_gecco", "read_cover"]


@dataclass(frozen=True, eq=False)
class CoverInstance:
    """A set-cover instance.

    Attributes
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix of float64
        1.0 where column ``j`` covers row ``i``.
    costs : (n,) float64
        Column costs.
    name : str
        Source file name.
    """

    matrix: sp.csr_matrix
    costs: np.ndarray
    name: str


def _ints(path: Path) -> np.ndarray:
    try:
        text = path.read_text(encoding="ascii", errors="replace")
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        return np.array(text.split(), dtype=np.int64)
    except ValueError:
        raise CamplaceError(f"{path}: expected whitespace-separated integers") from None


def read_orlib(path: str | Path) -> CoverInstance:
    """OR-Library ``scp*.txt``: ``m n``, n column costs, then per row a count and 1-based columns."""
    path = Path(path)
    v = _ints(path)
    try:
        m, n = int(v[0]), int(v[1])
        costs = v[2 : 2 + n].astype(np.float64)
        if costs.size != n:
            raise IndexError
        p = 2 + n
        rows, cols = [], []
        for i in range(m):
            c = int(v[p])
            js = v[p + 1 : p + 1 + c]
            if js.size != c:
                raise IndexError
            rows.append(np.full(c, i))
            cols.append(js - 1)
            p += 1 + c
    except IndexError:
        raise CamplaceError(f"{path}: truncated OR-Library set-cover file") from None
    r, c = np.concatenate(rows), np.concatenate(cols)
    if c.size and (c.min() < 0 or c.max() >= n):
        raise CamplaceError(f"{path}: column index out of range 1..{n}")
    mat = sp.csr_matrix((np.ones(r.size), (r, c)), shape=(m, n))
    mat.data[:] = 1.0
    return CoverInstance(mat, costs, path.name)


def read_gecco(path: str | Path) -> CoverInstance:
    """GECCO 2020 camera placement ``*_cover.txt``: ``n_points n_candidates``, then per point its
    index, a count and that many 0-based candidate indices (unit costs)."""
    path = Path(path)
    v = _ints(path)
    try:
        m, n = int(v[0]), int(v[1])
        p = 2
        rows, cols = [], []
        for i in range(m):
            c = int(v[p + 1])
            js = v[p + 2 : p + 2 + c]
            if js.size != c:
                raise IndexError
            rows.append(np.full(c, i))
            cols.append(js)
            p += 2 + c
    except IndexError:
        raise CamplaceError(f"{path}: truncated GECCO camera-placement file") from None
    r, c = np.concatenate(rows), np.concatenate(cols)
    if c.size and (c.min() < 0 or c.max() >= n):
        raise CamplaceError(f"{path}: candidate index out of range 0..{n - 1}")
    mat = sp.csr_matrix((np.ones(r.size), (r, c)), shape=(m, n))
    mat.data[:] = 1.0
    return CoverInstance(mat, np.ones(n), path.name)


def read_cover(path: str | Path, fmt: str) -> CoverInstance:
    """Read ``path`` in format ``"orlib"`` or ``"gecco"``."""
    if fmt == "orlib":
        return read_orlib(path)
    if fmt == "gecco":
        return read_gecco(path)
    raise CamplaceError(f"unknown set-cover format {fmt!r} (use orlib or gecco)")
