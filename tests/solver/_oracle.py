"""Test oracles for the solver: exhaustive enumeration and instance generators."""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp
from hypothesis import strategies as st

from camplace.solver._support.deadline import Deadline


def brute_force(matrix: sp.spmatrix | np.ndarray, weights: np.ndarray, k: int) -> tuple[float, list[tuple[int, ...]]]:
    """Optimum of max coverage by enumerating every k-subset.

    Parameters
    ----------
    matrix : (m, n) sparse or dense
        Values > 0 mean "observes".
    weights : (m,) float64
    k : int

    Returns
    -------
    best : float
        Optimal covered weight.
    optimal_sets : list of tuple of int
        Every k-subset attaining it (to within 1e-12 relative).
    """
    dense = (matrix.toarray() if sp.issparse(matrix) else np.asarray(matrix)) > 0
    m, n = dense.shape
    w = np.asarray(weights, dtype=np.float64)
    combos = np.array(list(itertools.combinations(range(n), k)), dtype=np.int64).reshape(-1, k)
    values = np.zeros(combos.shape[0])
    for c0 in range(0, combos.shape[0], 4096):
        block = combos[c0 : c0 + 4096]
        covered = dense[:, block].any(axis=2)  # (m, b)
        values[c0 : c0 + 4096] = w @ covered
    best = float(values.max()) if values.size else 0.0
    tol = 1e-12 * max(1.0, abs(best))
    sets = [tuple(int(j) for j in combos[i]) for i in np.flatnonzero(values >= best - tol)]
    return best, sets


def tolerance(weights: np.ndarray) -> float:
    """Comparison tolerance: the exact engine's float64 pruning margin plus rounding."""
    return 2e-9 * float(np.sum(weights)) + 1e-12


@st.composite
def small_instances(
    draw: st.DrawFn, max_n: int = 30, max_m: int = 40, max_k: int = 4
) -> tuple[sp.csr_matrix, np.ndarray, int]:
    """Random small instances with near-duplicate columns, identical rows and zero weights."""
    n0 = draw(st.integers(1, max_n))
    m = draw(st.integers(0, max_m))
    k = draw(st.integers(1, min(max_k, n0)))
    density = draw(st.sampled_from([0.05, 0.15, 0.3, 0.5, 0.8]))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n0)) < density) * rng.uniform(0.01, 1.0, size=(m, n0))
    # Near-duplicate and exact duplicate columns (neighbouring camera positions).
    n_dup = draw(st.integers(0, max(0, max_n - n0)))
    for _ in range(n_dup):
        col = dense[:, rng.integers(0, n0)].copy() if n0 else np.zeros(m)
        flips = int(rng.integers(0, 3)) if m else 0
        for i in rng.integers(0, max(m, 1), size=flips):
            col[i] = 0.0 if col[i] > 0 else 0.7
        dense = np.column_stack([dense, col])
    # Identical rows.
    if m >= 2:
        for _ in range(draw(st.integers(0, m // 2))):
            dense[rng.integers(0, m)] = dense[rng.integers(0, m)]
    kind = draw(st.sampled_from(["equal", "integer", "float", "tiny"]))
    if kind == "equal":
        w = np.full(m, 1.0 / max(m, 1))
    elif kind == "integer":
        w = rng.integers(0, 6, size=m).astype(np.float64)
    elif kind == "float":
        w = rng.uniform(0.0, 1.0, size=m)
    else:
        w = rng.uniform(0.0, 1e-6, size=m)
    for i in rng.choice(m, size=min(m, draw(st.integers(0, 5))), replace=False) if m else []:
        w[i] = 0.0
    return sp.csr_matrix(dense), w, k


# ---- oracles for camplace.solver.api (independent of the solver code) -------------------------


def mode_objective(dense: np.ndarray, w: np.ndarray, cols: tuple[int, ...], mode: str, views: int = 2,
                   min_angle_deg: float | None = None, pos: np.ndarray | None = None,
                   pts: np.ndarray | None = None) -> float:
    """Objective of camera set ``cols`` computed point by point from the definitions."""
    total = 0.0
    for i in range(dense.shape[0]):
        qs = [dense[i, j] for j in cols if dense[i, j] > 0]
        if mode in ("maxcover", "setcover"):
            total += w[i] if qs else 0.0
        elif mode == "quality":
            total += w[i] * (max(qs) if qs else 0.0)
        else:
            seen = [j for j in cols if dense[i, j] > 0]
            if len(seen) < views:
                continue
            if min_angle_deg is not None:
                ok = False
                for a, b in itertools.combinations(seen, 2):
                    u, v = pos[a] - pts[i], pos[b] - pts[i]
                    ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))
                    ok = ok or ang >= min_angle_deg
                if not ok:
                    continue
            total += w[i]
    return float(total)


def spaced(cols: tuple[int, ...], pos: np.ndarray | None, dmin: float | None) -> bool:
    """True when every pair of ``cols`` is at least ``dmin`` apart."""
    if dmin is None:
        return True
    return all(np.linalg.norm(pos[a] - pos[b]) >= dmin for a, b in itertools.combinations(cols, 2))


def brute_force_mode(dense, w, k, mode, *, views=2, min_angle_deg=None, pos=None, pts=None, fixed=(), forbidden=(),
                     dmin=None) -> float | None:
    """Best objective over every set of ``k`` new cameras (fixed kept, forbidden avoided); None if none is feasible."""
    n = dense.shape[1]
    free = [j for j in range(n) if j not in fixed and j not in forbidden]
    best = None
    for new in itertools.combinations(free, k):
        cols = tuple(sorted(set(fixed) | set(new)))
        if not spaced(cols, pos, dmin):
            continue
        v = mode_objective(dense, w, cols, mode, views, min_angle_deg, pos, pts)
        best = v if best is None or v > best else best
    return best


def usable(n, fixed, forbidden, pos=None, dmin=None) -> list[int]:
    """Cameras that may be used: not forbidden, and (with ``dmin``) not closer than ``dmin`` to a fixed one."""
    return [j for j in range(n) if j not in forbidden and (j in fixed or all(spaced((j, f), pos, dmin) for f in fixed))]


def brute_force_setcover(dense, w, costs, fraction=1.0, *, fixed=(), forbidden=(), pos=None, dmin=None):
    """Cheapest set of new cameras covering ``fraction`` of the coverable positive weight; None if infeasible."""
    n = dense.shape[1]
    allowed = usable(n, fixed, forbidden, pos, dmin)
    cover = (dense[:, allowed] > 0).any(axis=1) & (w > 0)
    target = fraction * float(w[cover].sum())
    free = [j for j in allowed if j not in fixed]
    best = None
    for r in range(len(free) + 1):
        for new in itertools.combinations(free, r):
            cols = tuple(sorted(set(fixed) | set(new)))
            if not spaced(cols, pos, dmin):
                continue
            got = mode_objective(dense, w, cols, "maxcover")
            if got >= target - 1e-9 * max(1.0, target):
                c = float(sum(costs[j] for j in new))
                best = c if best is None or c < best else best
    return best


class ExpiringDeadline(Deadline):
    """A stand-in for the solve's one ``Deadline`` that expires after ``checks`` checks
    (deterministic interruption of an engine's search): injected as an engine's ``deadline``, or
    as the deadline :func:`camplace.solver.solve` makes (``solve_deadline``). It has no limit:
    the slices cut from it (``share``, ``within``, ``shortened``) are itself (they expire with
    it), and ``remaining`` says 1 s until it expires."""

    def __init__(self, checks: int) -> None:
        super().__init__(None)
        self.left_checks = checks

    def expired(self) -> bool:
        self.left_checks -= 1
        return self.left_checks < 0

    def remaining(self) -> float:
        return 0.0 if self.left_checks < 0 else 1.0

    def share(self, fraction: float) -> "ExpiringDeadline":
        return self  # a step's slice expires with it

    within = shortened = share


def solve_deadline(monkeypatch, deadline: Deadline) -> None:
    """Make ``deadline`` the one deadline of the next solves (where :func:`camplace.solver.solve`
    makes it), instead of one from ``time_limit_s``."""
    import camplace.solver.api as api

    monkeypatch.setattr(api, "Deadline", lambda _limit: deadline)


class CountingDeadline(Deadline):
    """Expires after a fixed number of checks: interrupts an engine at a deterministic point
    (injected as an engine's ``deadline``, or as the solve's with :func:`solve_deadline`)."""

    def __init__(self, after: int) -> None:
        super().__init__(None)
        self.after, self.calls = after, 0

    def expired(self) -> bool:
        self.calls += 1
        return self.calls > self.after

    def remaining(self) -> float | None:
        return 1e-3 if self.calls > self.after else None

    def share(self, fraction: float) -> "CountingDeadline":
        return self  # a step's slice expires with it

    within = shortened = share
