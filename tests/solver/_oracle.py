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
#
# ``*_by_definition`` are the definitions, point by point and set by set in plain Python; the names
# the tests import (``mode_objective``, ``brute_force_mode``, ``brute_force_setcover``) compute the
# same numbers with numpy over every row and many sets at once, bit for bit: each row's term as the
# definition forms it, the rows added in order (``np.cumsum`` adds left to right, like the loop),
# and every minimum angle or distance that a vectorised rounding could put on the other side of
# the threshold decided by the definition's own scalar expression. tests/solver/test_oracle.py
# checks the two against each other.


def mode_objective_by_definition(dense: np.ndarray, w: np.ndarray, cols: tuple[int, ...], mode: str, views: int = 2,
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


def brute_force_mode_by_definition(dense, w, k, mode, *, views=2, min_angle_deg=None, pos=None, pts=None, fixed=(),
                                   forbidden=(), dmin=None) -> float | None:
    """Best objective over every set of ``k`` new cameras (fixed kept, forbidden avoided); None if none is feasible."""
    n = dense.shape[1]
    free = [j for j in range(n) if j not in fixed and j not in forbidden]
    best = None
    for new in itertools.combinations(free, k):
        cols = tuple(sorted(set(fixed) | set(new)))
        if not spaced(cols, pos, dmin):
            continue
        v = mode_objective_by_definition(dense, w, cols, mode, views, min_angle_deg, pos, pts)
        best = v if best is None or v > best else best
    return best


def _angle_ok(pos: np.ndarray, pts: np.ndarray, min_angle_deg: float) -> np.ndarray:
    """(m, n, n) bool: the angle at point i between cameras a and b is at least ``min_angle_deg``
    (the definition's expression; near the threshold, the definition's own scalar call)."""
    pos, pts = np.asarray(pos), np.asarray(pts)
    u = pos[None, :, :] - pts[:, None, :]  # (m, n, 3): point i to camera a
    cr = np.cross(u[:, :, None, :], u[:, None, :, :])  # (m, n, n, 3)
    dt = np.einsum("iak,ibk->iab", u, u)
    ang = np.degrees(np.arctan2(np.sqrt(np.einsum("iabk,iabk->iab", cr, cr)), dt))
    ok = ang >= min_angle_deg
    for i, a, b in zip(*np.nonzero(np.abs(ang - min_angle_deg) <= 1e-6 * max(1.0, abs(min_angle_deg))), strict=True):
        uu, vv = pos[a] - pts[i], pos[b] - pts[i]
        ok[i, a, b] = np.degrees(np.arctan2(np.linalg.norm(np.cross(uu, vv)), np.dot(uu, vv))) >= min_angle_deg
    return ok


def _row_sums(terms: np.ndarray) -> np.ndarray:
    """Column sums of (m, b) ``terms`` added row after row (the loop's order, so the same bits)."""
    terms = np.asarray(terms)
    if terms.dtype.kind in "biu":  # the loop's 0.0 + an integer weight is a float64
        terms = terms.astype(np.float64)
    if terms.shape[0] == 0:
        return np.zeros(terms.shape[1:])
    return np.cumsum(terms, axis=0)[-1]


class _Sets:
    """The objective of many camera sets at once (rows of ``cols``, (b, L) int), by the definitions."""

    def __init__(self, dense, w, mode, views=2, min_angle_deg=None, pos=None, pts=None, use=()) -> None:
        d = dense.toarray() if sp.issparse(dense) else np.asarray(dense)
        self.seen = d > 0
        self.q = np.where(self.seen, d, 0) if mode == "quality" else None
        self.w = np.asarray(w)
        self.mode, self.views = mode, views
        self.angle = None
        if mode not in ("maxcover", "setcover", "quality") and min_angle_deg is not None:
            use = np.unique(np.asarray(list(use), dtype=np.int64))  # the columns the sets draw from
            self.slot = np.full(d.shape[1], -1, dtype=np.int64)
            self.slot[use] = np.arange(use.size)
            self.angle = _angle_ok(np.asarray(pos)[use], pts, min_angle_deg)

    def values(self, cols: np.ndarray) -> np.ndarray:
        m = self.seen.shape[0]
        b, L = cols.shape
        seen = self.seen[:, cols]  # (m, b, L)
        w = self.w[:, None]
        if self.mode in ("maxcover", "setcover"):
            return _row_sums(np.where(seen.any(axis=2), w, 0.0))
        if self.mode == "quality":
            q = self.q[:, cols].max(axis=2) if L else np.zeros((m, b), dtype=self.q.dtype)
            return _row_sums(w * q)
        ok = seen.sum(axis=2) >= self.views
        if self.angle is not None:
            pair = np.zeros((m, b), dtype=bool)
            for s, t in itertools.combinations(range(L), 2):
                pair |= seen[:, :, s] & seen[:, :, t] & self.angle[:, self.slot[cols[:, s]], self.slot[cols[:, t]]]
            ok &= pair
        return _row_sums(np.where(ok, w, 0.0))


def _spaced_sets(cols: np.ndarray, pos, dmin) -> np.ndarray:
    """(b,) bool: :func:`spaced` of every row of ``cols`` (the distances by its own expression)."""
    keep = np.ones(cols.shape[0], dtype=bool)
    if dmin is None:
        return keep
    pos = np.asarray(pos)
    n = pos.shape[0]
    far = np.ones((n, n), dtype=bool)
    for a, b in itertools.combinations(np.unique(cols).tolist(), 2):
        far[a, b] = far[b, a] = np.linalg.norm(pos[a] - pos[b]) >= dmin
    for s, t in itertools.combinations(range(cols.shape[1]), 2):
        keep &= far[cols[:, s], cols[:, t]]
    return keep


def _combos(free: list[int], r: int, fixed) -> np.ndarray:
    """Every set of ``r`` new cameras from ``free`` with the fixed ones, (b, len(fixed) + r) int."""
    if r == 0:
        new = np.zeros((1, 0), dtype=np.int64)  # the one empty set
    else:
        new = np.array(list(itertools.combinations(free, r)), dtype=np.int64).reshape(-1, r)
    fix = np.array(sorted(set(fixed)), dtype=np.int64)
    return np.hstack([np.broadcast_to(fix, (new.shape[0], fix.size)), new])


_BLOCK = 2048


def mode_objective(dense: np.ndarray, w: np.ndarray, cols: tuple[int, ...], mode: str, views: int = 2,
                   min_angle_deg: float | None = None, pos: np.ndarray | None = None,
                   pts: np.ndarray | None = None) -> float:
    """Objective of camera set ``cols`` (:func:`mode_objective_by_definition`, the same bits)."""
    cols = np.asarray(list(cols), dtype=np.int64).reshape(1, -1)
    sets = _Sets(dense, w, mode, views, min_angle_deg, pos, pts, use=cols.ravel())
    return float(sets.values(cols)[0])


def brute_force_mode(dense, w, k, mode, *, views=2, min_angle_deg=None, pos=None, pts=None, fixed=(), forbidden=(),
                     dmin=None) -> float | None:
    """Best objective over every set of ``k`` new cameras (fixed kept, forbidden avoided); None if none is feasible.
    (:func:`brute_force_mode_by_definition`, the same bits.)"""
    n = dense.shape[1]
    free = [j for j in range(n) if j not in fixed and j not in forbidden]
    sets = _Sets(dense, w, mode, views, min_angle_deg, pos, pts, use=[*free, *fixed])
    cols = _combos(free, k, fixed)
    best = None
    for c0 in range(0, cols.shape[0], _BLOCK):
        block = cols[c0 : c0 + _BLOCK]
        block = block[_spaced_sets(block, pos, dmin)]
        if block.shape[0]:
            v = float(sets.values(block).max())
            best = v if best is None or v > best else best
    return best


def usable(n, fixed, forbidden, pos=None, dmin=None) -> list[int]:
    """Cameras that may be used: not forbidden, and (with ``dmin``) not closer than ``dmin`` to a fixed one."""
    return [j for j in range(n) if j not in forbidden and (j in fixed or all(spaced((j, f), pos, dmin) for f in fixed))]


def brute_force_setcover_by_definition(dense, w, costs, fraction=1.0, *, fixed=(), forbidden=(), pos=None, dmin=None):
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
            got = mode_objective_by_definition(dense, w, cols, "maxcover")
            if got >= target - 1e-9 * max(1.0, target):
                c = float(sum(costs[j] for j in new))
                best = c if best is None or c < best else best
    return best


def brute_force_setcover(dense, w, costs, fraction=1.0, *, fixed=(), forbidden=(), pos=None, dmin=None):
    """Cheapest set of new cameras covering ``fraction`` of the coverable positive weight; None if infeasible.
    (:func:`brute_force_setcover_by_definition`, the same bits.)"""
    n = dense.shape[1]
    allowed = usable(n, fixed, forbidden, pos, dmin)
    cover = (dense[:, allowed] > 0).any(axis=1) & (w > 0)
    target = fraction * float(w[cover].sum())
    free = [j for j in allowed if j not in fixed]
    sets = _Sets(dense, w, "maxcover")
    nfix = len(set(fixed))
    best = None
    for r in range(len(free) + 1):
        cols = _combos(free, r, fixed)
        for c0 in range(0, cols.shape[0], _BLOCK):
            block = cols[c0 : c0 + _BLOCK]
            block = block[_spaced_sets(block, pos, dmin)]
            if not block.shape[0]:
                continue
            got = sets.values(block)
            block = block[got >= target - 1e-9 * max(1.0, target)]
            if not block.shape[0]:
                continue
            new = block[:, nfix:]
            c = np.cumsum(np.asarray(costs)[new], axis=1)[:, -1] if r else np.zeros(block.shape[0])
            v = float(c.min())
            best = v if best is None or v < best else best
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


def random_observations(rng: np.random.Generator, m: int, n: int, density: float,
                        graded: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(dense (m, n) float32, weights (m,)): each pair observed with probability ``density``
    (qualities 0.25 / 0.5 / 1 when ``graded``), a tenth of the rows weightless."""
    dense = (rng.random((m, n)) < density).astype(np.float32)
    if graded:
        dense *= rng.choice([0.25, 0.5, 1.0], size=dense.shape).astype(np.float32)
    w = np.where(rng.random(m) < 0.1, 0.0, rng.random(m) + 0.1)
    return dense, w
