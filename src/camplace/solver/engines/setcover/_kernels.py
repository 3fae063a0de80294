"""Compiled (numba) kernels of the set-cover engine (:mod:`camplace.solver.engines.setcover.local_search`).

The instance is held twice, as a column-major list (``cptr``, ``crow``: the rows of column ``j``
are ``crow[cptr[j]:cptr[j + 1]]``) and a row-major one (``rptr``, ``rcol``). Every kernel is
GIL-free and deterministic: the local search draws from its own xorshift64* generator, stored
with the rest of its state in plain arrays, so running ``N`` iterations in one call or in several
gives the same result.

Local-search state (arrays, updated in place):

``x`` (n,) int8
    1 when column ``j`` is in the current solution ``S``.
``cov`` (m,) int32
    Number of columns of ``S`` covering row ``i``; ``csum`` (m,) int64 their index sum, so the
    only coverer of a row with ``cov == 1`` is ``csum`` itself.
``pw`` (m,) float64
    Row penalty weights (start at 1, or at the row weight for partial covers).
``score`` (n,) float64
    For ``j`` in ``S``: minus the penalty of the rows only ``j`` covers (the loss of removing it).
    For ``j`` outside ``S``: the penalty of the uncovered rows it covers (the gain of adding it).
``stamp`` (n,) int64
    Iteration of the last change of column ``j`` (ties go to the column unchanged for longest).
``sel``/``selpos``, ``unc``/``uncpos``
    Index lists (with positions, -1 when absent) of ``S`` and of the uncovered rows.
``best`` (n,) int8
    The cheapest feasible solution seen.
``ist`` int64: [iteration, |S|, uncovered rows, last added, last removed, iteration of the best,
improvements, work, work at the best, work at the last improvement or restart, restarts]; ``fst``
float64: [cost of S, covered row weight, cost of the best]; ``rng`` uint64 [1]. Work counts the inner-loop steps (score updates, candidates), a
measure of effort that does not depend on the machine.
"""

from __future__ import annotations

import numba
import numpy as np

from camplace._bitops import ctz as _ctz, popcount as _popc

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}

# ist slots
IT, NSEL, NUNC, LADD, LREM, BEST_IT, IMPROVED, WORK, BEST_WORK, EPOCH_WORK, RESTARTS = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10
N_IST = 11
# fst slots
COST, COVW, BEST_COST = 0, 1, 2
N_FST = 3


# ----------------------------------------------------------------------------------------------
# reductions
# ----------------------------------------------------------------------------------------------


@numba.njit(**_JIT)
def bitsets(ptr, idx, n_items, n_bits):  # pragma: no cover - compiled
    """(n_items, ceil(n_bits / 64)) uint64 bitsets of a compressed list (item ``a`` holds bits
    ``idx[ptr[a]:ptr[a + 1]]``)."""
    n_words = (n_bits + 63) // 64
    out = np.zeros((n_items, max(n_words, 1)), dtype=np.uint64)
    for a in range(n_items):
        for p in range(ptr[a], ptr[a + 1]):
            b = idx[p]
            out[a, b >> 6] |= np.uint64(1) << np.uint64(b & 63)
    return out


@numba.njit(**_JIT)
def subset_marks(bits, size, ptr, idx, other_ptr, other_idx, key, mark_superset):  # pragma: no cover - compiled
    """Mark items that are in a strict "subset order" with another item.

    For every item ``a`` (bitset ``bits[a]`` of ``size[a]`` elements), the items ``b`` containing
    ``a``'s rarest element (``other_idx[other_ptr[e]:other_ptr[e + 1]]``, the items of element
    ``e``) are tested for ``a`` being a subset of ``b``, word by word.

    * ``mark_superset`` False (column dominance): ``a`` is marked when it is a subset of some ``b``
      with ``key[b] < key[a]`` or (``key[b] == key[a]`` and (``size[b] > size[a]`` or, identical,
      ``b < a``)).
    * ``mark_superset`` True (row dominance): ``b`` is marked when ``a`` is a subset of it and
      ``size[a] < size[b]`` or (identical) ``a < b``.

    Both relations are strict orders, so every marked item has an unmarked one in the relation.

    Parameters
    ----------
    bits : (n_items, words) uint64
    size : (n_items,) int64
    ptr, idx : compressed list item -> elements
    other_ptr, other_idx : compressed list element -> items
    key : (n_items,) float64
        Column costs (column dominance; ignored for rows).
    mark_superset : bool

    Returns
    -------
    (n_items,) bool
    """
    n_items, n_words = bits.shape
    out = np.zeros(n_items, dtype=np.bool_)
    for a in range(n_items):
        if size[a] == 0:
            continue
        if mark_superset is False and out[a]:
            continue
        best_e = -1
        best_cnt = np.int64(1) << 62
        for p in range(ptr[a], ptr[a + 1]):
            e = idx[p]
            c = other_ptr[e + 1] - other_ptr[e]
            if c < best_cnt:
                best_cnt = c
                best_e = e
        for q in range(other_ptr[best_e], other_ptr[best_e + 1]):
            if _mark_pair(a, other_idx[q], bits, size, key, mark_superset, out):
                break
    return out


@numba.njit(**_JIT)
def _mark_pair(a, b, bits, size, key, mark_superset, out):  # pragma: no cover - compiled
    """One candidate ``b`` of item ``a`` in :func:`subset_marks` / :func:`subset_marks_bits`: mark
    ``b`` (a superset of ``a``, rows) or ``a`` (a subset of ``b`` at no lower key, columns) under
    the relations' tie rules; True when ``a`` is marked (its scan ends)."""
    if b == a or size[b] < size[a]:
        return False
    if mark_superset:
        if out[b] or (size[b] == size[a] and b < a):
            return False
    else:
        if key[b] > key[a]:
            return False
        if key[b] == key[a] and size[b] == size[a] and b > a:
            return False
    for wd in range(bits.shape[1]):
        if bits[a, wd] & ~bits[b, wd]:
            return False
    if mark_superset:
        out[b] = True
        return False
    out[a] = True
    return True


@numba.njit(**_JIT)
def _take_cheaper(i, j, c, c1, j1, c2):  # pragma: no cover - compiled
    """Row ``i``'s cheapest (``c1``, its column ``j1``, the lowest index among equal costs) and
    second cheapest (``c2``) alive column so far, given column ``j`` of cost ``c``."""
    if c < c1[i] or (c == c1[i] and j < j1[i]):
        c2[i] = c1[i]
        c1[i] = c
        j1[i] = j
    elif c < c2[i]:
        c2[i] = c


@numba.njit(**_JIT)
def cheaper_cover_marks(cptr, crow, rptr, rcol, cost, alive):  # pragma: no cover - compiled
    """Columns costing strictly more than covering each of their rows by its cheapest other column.

    Such a column is in no optimal cover (replace it by those columns), so all marked columns can be
    dropped together.

    Returns
    -------
    (n,) bool
    """
    n = cptr.shape[0] - 1
    m = rptr.shape[0] - 1
    # cheapest and second cheapest alive column of every row
    c1 = np.full(m, np.inf)
    j1 = np.full(m, -1, dtype=np.int64)
    c2 = np.full(m, np.inf)
    for i in range(m):
        for p in range(rptr[i], rptr[i + 1]):
            j = rcol[p]
            if alive[j]:
                _take_cheaper(i, j, cost[j], c1, j1, c2)
    out = np.zeros(n, dtype=np.bool_)
    for j in range(n):
        if not alive[j]:
            continue
        s = 0.0
        for p in range(cptr[j], cptr[j + 1]):
            i = crow[p]
            s += c2[i] if j1[i] == j else c1[i]
            if s >= cost[j]:
                break
        if s < cost[j] * (1.0 - 1e-12):
            out[j] = True
    return out


# ----------------------------------------------------------------------------------------------
# reductions on bitsets (the rows to cover of a binary matrix held as bits: no CSR lists)
# ----------------------------------------------------------------------------------------------


@numba.njit(**_JIT)
def bit_counts(bits):  # pragma: no cover - compiled
    """(n_items,) int64: set bits of every item of ``bits`` (n_items, words) uint64."""
    n_items, n_words = bits.shape
    out = np.zeros(n_items, dtype=np.int64)
    for a in range(n_items):
        s = np.int64(0)
        for wd in range(n_words):
            s += np.int64(_popc(bits[a, wd]))
        out[a] = s
    return out


@numba.njit(**_JIT)
def lowest_bits(bits, items):  # pragma: no cover - compiled
    """(k,) int64: the lowest set bit of each item of ``items`` (-1 for an empty item)."""
    out = np.full(items.shape[0], -1, dtype=np.int64)
    for t in range(items.shape[0]):
        a = items[t]
        for wd in range(bits.shape[1]):
            x = bits[a, wd]
            if x:
                out[t] = (np.int64(wd) << 6) + np.int64(_ctz(x))
                break
    return out


@numba.njit(**_JIT)
def subset_marks_bits(bits, size, ebits, ecount, key, mark_superset):  # pragma: no cover - compiled
    """:func:`subset_marks` read from bitsets instead of compressed lists, with the same result.

    The elements of item ``a`` are the set bits of ``bits[a]`` (ascending, as ``idx`` of a sorted
    list), the items holding element ``e`` the set bits of ``ebits[e]`` (ascending) and their number
    ``ecount[e]``; the rarest element (first of the least count), the candidates' order and the
    marks are those of :func:`subset_marks`.

    Parameters
    ----------
    bits : (n_items, ceil(n_elements / 64)) uint64
    size : (n_items,) int64
        Set bits of every item.
    ebits : (n_elements, ceil(n_items / 64)) uint64
        The transposition of ``bits``.
    ecount : (n_elements,) int64
        Set bits of every element.
    key : (n_items,) float64
    mark_superset : bool

    Returns
    -------
    (n_items,) bool
    """
    n_items, n_words = bits.shape
    n_ewords = ebits.shape[1]
    out = np.zeros(n_items, dtype=np.bool_)
    for a in range(n_items):
        if size[a] == 0:
            continue
        if mark_superset is False and out[a]:
            continue
        best_e = -1
        best_cnt = np.int64(1) << 62
        for wd in range(n_words):
            x = bits[a, wd]
            while x:
                e = (np.int64(wd) << 6) + np.int64(_ctz(x))
                x &= x - np.uint64(1)
                c = ecount[e]
                if c < best_cnt:
                    best_cnt = c
                    best_e = e
        done = False
        for wq in range(n_ewords):
            y = ebits[best_e, wq]
            while y:
                b = (np.int64(wq) << 6) + np.int64(_ctz(y))
                y &= y - np.uint64(1)
                if _mark_pair(a, b, bits, size, key, mark_superset, out):
                    done = True
                    break
            if done:
                break
    return out


@numba.njit(**_JIT)
def cheaper_cover_marks_bits(cbits, rbits, cost, alive):  # pragma: no cover - compiled
    """:func:`cheaper_cover_marks` read from the column bitsets ``cbits`` (n, ceil(m / 64)) and the
    row bitsets ``rbits`` (m, ceil(n / 64)) uint64, with the same result.

    Returns
    -------
    (n,) bool
    """
    n = cbits.shape[0]
    m = rbits.shape[0]
    c1 = np.full(m, np.inf)
    j1 = np.full(m, -1, dtype=np.int64)
    c2 = np.full(m, np.inf)
    for i in range(m):
        for wd in range(rbits.shape[1]):
            x = rbits[i, wd]
            while x:
                j = (np.int64(wd) << 6) + np.int64(_ctz(x))
                x &= x - np.uint64(1)
                if alive[j]:
                    _take_cheaper(i, j, cost[j], c1, j1, c2)
    out = np.zeros(n, dtype=np.bool_)
    for j in range(n):
        if not alive[j]:
            continue
        s = 0.0
        stop = False
        for wd in range(cbits.shape[1]):
            x = cbits[j, wd]
            while x:
                i = (np.int64(wd) << 6) + np.int64(_ctz(x))
                x &= x - np.uint64(1)
                s += c2[i] if j1[i] == j else c1[i]
                if s >= cost[j]:
                    stop = True
                    break
            if stop:
                break
        if s < cost[j] * (1.0 - 1e-12):
            out[j] = True
    return out


@numba.njit(**_JIT)
def compact_bits(bits, items, bit_map, lo, hi, out):  # pragma: no cover - compiled
    """``out[t]`` = item ``items[t]`` of ``bits`` with its bits renumbered (bit ``b`` becomes
    ``bit_map[b]``; -1 drops it), for ``t`` in ``lo:hi`` (``out`` zeroed by the caller)."""
    for t in range(lo, hi):
        a = items[t]
        for wd in range(bits.shape[1]):
            x = bits[a, wd]
            while x:
                b = bit_map[(np.int64(wd) << 6) + np.int64(_ctz(x))]
                x &= x - np.uint64(1)
                if b >= 0:
                    out[t, b >> 6] |= np.uint64(1) << np.uint64(b & 63)


# ----------------------------------------------------------------------------------------------
# local search
# ----------------------------------------------------------------------------------------------


@numba.njit(**_JIT)
def _rand(rng):  # pragma: no cover - compiled
    """Next xorshift64* draw (uint64)."""
    v = rng[0]
    v ^= v >> np.uint64(12)
    v ^= v << np.uint64(25)
    v ^= v >> np.uint64(27)
    rng[0] = v
    return v * np.uint64(0x2545F4914F6CDD1D)


@numba.njit(**_JIT)
def _unc_add(i, unc, uncpos, ist):  # pragma: no cover - compiled
    uncpos[i] = ist[NUNC]
    unc[ist[NUNC]] = i
    ist[NUNC] += 1


@numba.njit(**_JIT)
def _unc_del(i, unc, uncpos, ist):  # pragma: no cover - compiled
    p = uncpos[i]
    last = unc[ist[NUNC] - 1]
    unc[p] = last
    uncpos[last] = p
    uncpos[i] = -1
    ist[NUNC] -= 1


@numba.njit(**_JIT)
def add_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
            uncpos, ist, fst):  # pragma: no cover - compiled
    """Put column ``j`` into the solution and update every score incrementally."""
    x[j] = 1
    selpos[j] = ist[NSEL]
    sel[ist[NSEL]] = j
    ist[NSEL] += 1
    fst[COST] += cost[j]
    score[j] = -score[j]
    stamp[j] = ist[IT]
    ist[WORK] += cptr[j + 1] - cptr[j]
    for p in range(cptr[j], cptr[j + 1]):
        i = crow[p]
        c = cov[i]
        if c == 0:
            fst[COVW] += roww[i]
            _unc_del(i, unc, uncpos, ist)
            ist[WORK] += rptr[i + 1] - rptr[i]
            w = pw[i]  # a local: the stores into score could alias pw for the compiler
            for q in range(rptr[i], rptr[i + 1]):
                k = rcol[q]
                if k != j:
                    score[k] -= w
        elif c == 1:
            score[csum[i]] += pw[i]
        cov[i] = c + 1
        csum[i] += j


@numba.njit(**_JIT)
def remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
               uncpos, ist, fst, inc=0.0, pinc=None):  # pragma: no cover - compiled
    """Take column ``j`` out of the solution and update every score incrementally; the penalty of
    every row ``i`` it leaves uncovered rises by ``inc`` (times ``pinc[i]`` when given) on the way
    (the same as :func:`_bump` after)."""
    x[j] = 0
    p0 = selpos[j]
    last = sel[ist[NSEL] - 1]
    sel[p0] = last
    selpos[last] = p0
    selpos[j] = -1
    ist[NSEL] -= 1
    fst[COST] -= cost[j]
    score[j] = -score[j]
    stamp[j] = ist[IT]
    ist[WORK] += cptr[j + 1] - cptr[j]
    for p in range(cptr[j], cptr[j + 1]):
        i = crow[p]
        c = cov[i] - 1
        cov[i] = c
        csum[i] -= j
        if c == 0:
            fst[COVW] -= roww[i]
            _unc_add(i, unc, uncpos, ist)
            ist[WORK] += rptr[i + 1] - rptr[i]
            if inc != 0.0:
                d = inc if pinc is None else inc * pinc[i]
                pw[i] += d
                score[j] += d
            w = pw[i]
            for q in range(rptr[i], rptr[i + 1]):
                k = rcol[q]
                if k != j:
                    score[k] += w
        elif c == 1:
            score[csum[i]] -= pw[i]


@numba.njit(**_JIT)
def _pick_remove(tabu, cost, score, stamp, sel, ist):  # pragma: no cover - compiled
    """Column of S with the smallest loss per unit cost (ties: the dearer, then the older);
    ``tabu`` only if it is the only one."""
    ist[WORK] += ist[NSEL]
    best = -1
    br = 0.0
    for t in range(ist[NSEL]):
        j = sel[t]
        if j == tabu and ist[NSEL] > 1:
            continue
        r = score[j] / cost[j]
        if best < 0 or r > br or (r == br and (cost[j] > cost[best]
                                               or (cost[j] == cost[best] and stamp[j] < stamp[best]))):
            best = j
            br = r
    return best


@numba.njit(**_JIT)
def _pick_add(i, tabu, budget, rptr, rcol, cost, score, stamp, ist):  # pragma: no cover - compiled
    """Column covering row ``i`` with the largest gain per unit cost (ties: the older), among
    those cheaper than ``budget`` if any; ``tabu`` only if it is the only one."""
    ist[WORK] += rptr[i + 1] - rptr[i]
    best = -1
    br = 0.0
    fits = False
    for q in range(rptr[i], rptr[i + 1]):
        k = rcol[q]
        if k == tabu and rptr[i + 1] - rptr[i] > 1:
            continue
        f = cost[k] < budget
        if best >= 0 and fits and not f:
            continue
        r = score[k] / cost[k]
        if best < 0 or (f and not fits) or r > br or (r == br and stamp[k] < stamp[best]):
            best = k
            br = r
            fits = f
    return best


@numba.njit(**_JIT)
def _feasible(need, ist, fst):  # pragma: no cover - compiled
    if need < 0:
        return ist[NUNC] == 0
    return fst[COVW] >= need


@numba.njit(**_JIT)
def _covered_weight(cov, roww):  # pragma: no cover - compiled
    s = 0.0
    for i in range(cov.shape[0]):
        if cov[i] > 0:
            s += roww[i]
    return s


@numba.njit(**_JIT)
def greedy(cptr, crow, rptr, rcol, cost, roww, need, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
           ist, fst):  # pragma: no cover - compiled
    """Greedy cover from the empty solution (largest penalty gain per unit cost first), then drop
    redundant columns, dearest first. The state must be the empty solution with its scores."""
    n = cptr.shape[0] - 1
    while not _feasible(need, ist, fst):
        best = -1
        br = 0.0
        for j in range(n):
            if x[j] or score[j] <= 0:
                continue
            r = score[j] / cost[j]
            if best < 0 or r > br:
                best = j
                br = r
        if best < 0:
            break
        add_col(best, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
                uncpos, ist, fst)
    prune(cptr, crow, rptr, rcol, cost, roww, need, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos, ist, fst)


@numba.njit(**_JIT)
def _unique_weight(j, cptr, crow, cov, roww):  # pragma: no cover - compiled
    s = 0.0
    for p in range(cptr[j], cptr[j + 1]):
        i = crow[p]
        if cov[i] == 1:
            s += roww[i]
    return s


@numba.njit(**_JIT)
def prune(cptr, crow, rptr, rcol, cost, roww, need, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
          ist, fst):  # pragma: no cover - compiled
    """Remove redundant columns of S, dearest first (ties: the higher index), while S stays
    feasible (full cover: a column is redundant when no row depends on it alone)."""
    k = ist[NSEL]
    order = np.empty(k, dtype=np.int64)
    for t in range(k):
        order[t] = sel[t]
    # dearest first, then higher index first (deterministic)
    keys = np.empty(k, dtype=np.float64)
    for t in range(k):
        keys[t] = -cost[order[t]]
    idx = np.argsort(keys, kind="mergesort")
    order = order[idx]
    # within equal cost, sort by index descending (stable insertion sort on small arrays)
    for a in range(1, k):
        v = order[a]
        b = a - 1
        while b >= 0 and cost[order[b]] == cost[v] and order[b] < v:
            order[b + 1] = order[b]
            b -= 1
        order[b + 1] = v
    for t in range(k):
        j = order[t]
        if need < 0:
            redundant = True
            for p in range(cptr[j], cptr[j + 1]):
                if cov[crow[p]] == 1:
                    redundant = False
                    break
        else:
            redundant = _covered_weight(cov, roww) - _unique_weight(j, cptr, crow, cov, roww) >= need
        if redundant:
            remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos,
                       unc, uncpos, ist, fst)


@numba.njit(**_JIT)
def _record(x, best, cov, roww, need, ist, fst):  # pragma: no cover - compiled
    """Keep S as the best solution if it is cheaper (partial covers: re-checked exactly)."""
    if fst[COST] >= fst[BEST_COST] - 1e-9 * abs(fst[BEST_COST]) - 1e-300:
        return
    if need >= 0:
        w = _covered_weight(cov, roww)
        fst[COVW] = w  # resynchronise the incremental sum
        if w < need:
            return
    best[:] = x
    fst[BEST_COST] = fst[COST]
    ist[BEST_IT] = ist[IT]
    ist[BEST_WORK] = ist[WORK]
    ist[EPOCH_WORK] = ist[WORK]
    ist[IMPROVED] += 1


@numba.njit(**_JIT)
def _bump(i, rptr, rcol, pw, score, inc, ist):  # pragma: no cover - compiled
    """Raise the penalty of the uncovered row ``i`` (every column covering it gains)."""
    ist[WORK] += rptr[i + 1] - rptr[i]
    pw[i] += inc
    for q in range(rptr[i], rptr[i + 1]):
        score[rcol[q]] += inc


@numba.njit(**_JIT)
def _best_swap(i, budget, cptr, crow, rptr, rcol, cost, cov, csum, pw, score, stamp, sel, ist, ov, order_buf,
               max_cand):  # pragma: no cover - compiled
    """Best move (add ``k`` covering row ``i``, then remove ``j`` from S or nothing) keeping the cost
    of S below ``budget`` more than now: least penalty of the uncovered rows afterwards.

    Adding ``k`` gains ``score[k]``; removing ``j`` afterwards loses ``-score[j]`` minus ``ov[j]``,
    the penalty of the rows only ``j`` covers that ``k`` covers too. Candidates ``k`` are tried by
    decreasing gain and the scan stops once no gain can beat the best move (a move's change is at
    least ``-score[k]``), or after ``max_cand`` candidates. The column just added (``ist[LADD]``)
    is not removed and the one just removed (``ist[LREM]``) not added, unless nothing else is
    possible.

    Returns
    -------
    k, j : int
        ``j = -1``: add only; ``k = -1``: no move fits the budget.
    """
    deg = rptr[i + 1] - rptr[i]
    for q in range(deg):
        order_buf[q] = -score[rcol[rptr[i] + q]] / cost[rcol[rptr[i] + q]]
    order = np.argsort(order_buf[:deg])
    ist[WORK] += deg
    bk = -1
    bj = -1
    bd = np.inf
    bt = np.int64(0)
    tried = 0
    for t in range(deg):
        k = rcol[rptr[i] + order[t]]
        if k == ist[LREM] and deg > 1:
            continue
        if -score[k] > bd or tried >= max_cand:
            break
        tried += 1
        ist[WORK] += 2 * (cptr[k + 1] - cptr[k]) + ist[NSEL]
        if cost[k] < budget:  # add only
            d = -score[k]
            ts = stamp[k]
            if d < bd or (d == bd and ts < bt):
                bk, bj, bd, bt = k, -1, d, ts
            continue
        for p in range(cptr[k], cptr[k + 1]):
            r = crow[p]
            if cov[r] == 1:
                ov[csum[r]] += pw[r]
        for u in range(ist[NSEL]):
            j = sel[u]
            if j == ist[LADD] and ist[NSEL] > 1:
                continue
            if cost[k] - cost[j] >= budget:
                continue
            d = -score[k] - score[j] - ov[j]
            ts = stamp[k] + stamp[j]
            if d < bd or (d == bd and ts < bt):
                bk, bj, bd, bt = k, j, d, ts
        for p in range(cptr[k], cptr[k + 1]):
            r = crow[p]
            if cov[r] == 1:
                ov[csum[r]] = 0.0
    return bk, bj


@numba.njit(inline="always", **_JIT)
def _stop(ist, fst, target, stop_it, patience, restart):  # pragma: no cover - compiled
    """Why a search stops before its next step (as :func:`search` returns it), 0 to go on: 1 the
    target cost is reached, 2 the iteration budget is spent, 4 patience (work since the best) ran out,
    5 the work since the last improvement or restart reached ``restart`` (time to restart)."""
    if fst[BEST_COST] <= target:
        return 1
    if ist[IT] >= stop_it:
        return 2
    if ist[WORK] - 2 * ist[BEST_WORK] >= patience:
        return 4
    if ist[WORK] - ist[EPOCH_WORK] >= restart:
        return 5
    return 0


@numba.njit(**_JIT)
def search(cptr, crow, rptr, rcol, cost, roww, need, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
           best, ist, fst, rng, steps, target, stop_it, patience, max_cand, joint, pinc,
           restart):  # pragma: no cover - compiled
    """Row-weighting local search for ``steps`` iterations (after RWLS of Gao, Weise and Li 2015, with
    the joint swap move of fontanf/setcoveringsolver and costs).

    One iteration: if S is feasible, it becomes the best when cheaper, and its column of smallest
    loss per cost is removed. Otherwise, with equal costs: draw a random uncovered row and make
    the best joint move of :func:`_best_swap` (add a column covering it and remove one, S staying
    one column smaller than the best). With costs (or when no joint move fits): remove columns of
    smallest loss per cost (not the one just added) while S plus the cheapest column would not be
    cheaper than the best, add the column of largest gain per cost covering a random uncovered row
    (not the one just removed; one that keeps S cheaper than the best if any), and make room for it
    if needed. Then raise the penalty of every uncovered row ``i`` by ``pinc[i]`` (partial covers: of
    one random uncovered row, by 1). Stops early when the best cost reaches ``target``, the iteration
    count ``stop_it``, on patience or for a restart (``restart``, see :func:`_stop`).

    Returns
    -------
    int
        1 if ``target`` was reached, 2 if ``stop_it`` was, 3 if every row is covered and the
        required weight still not reached (partial cover with ``need`` above the total), 4 if the
        work since the best cover (score updates, counted in ``ist[WORK]``) exceeds ``patience``
        plus the work it took to find it, 5 if the work since the last improvement or restart
        reached ``restart``, else 0.
    """
    cmin = np.inf
    unit = joint
    for j in range(cost.shape[0]):
        cmin = min(cmin, cost[j])
        unit = unit and cost[j] == cost[0]
    ov = np.zeros(cost.shape[0])
    order_buf = np.empty(cost.shape[0])
    for _ in range(steps):
        tol = 1e-9 * abs(fst[BEST_COST])
        why = _stop(ist, fst, target, stop_it, patience, restart)
        if why:
            return why
        ist[IT] += 1
        if _feasible(need, ist, fst):
            _record(x, best, cov, roww, need, ist, fst)
            if ist[NSEL] == 0:
                return 1  # the empty set is feasible: nothing cheaper exists
            j = _pick_remove(-1, cost, score, stamp, sel, ist)
            remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos,
                       unc, uncpos, ist, fst)
            continue
        if ist[NUNC] == 0:  # partial cover, drifted incremental weight: resynchronise
            fst[COVW] = _covered_weight(cov, roww)
            if fst[COVW] < need:
                return 3
            continue
        if unit:
            # unit costs: the best joint move (S keeps one column fewer than the best)
            i = unc[np.int64((_rand(rng) >> np.uint64(11)) % np.uint64(ist[NUNC]))]
            k, j = _best_swap(i, fst[BEST_COST] - tol - fst[COST], cptr, crow, rptr, rcol, cost, cov, csum, pw, score,
                              stamp, sel, ist, ov, order_buf, max_cand)
        else:
            k = -1
        if k >= 0:
            add_col(k, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
                    ist, fst)
            ist[LADD] = k
            if j >= 0:
                remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
                           uncpos, ist, fst)
                ist[LREM] = j
        else:
            # costs (or no joint move fits): make room while even the cheapest column would not leave
            # S cheaper than the best, add the column of largest gain per cost covering a random
            # uncovered row (not the one just removed), make room for it if needed
            while ist[NSEL] > 0 and fst[COST] + cmin >= fst[BEST_COST] - tol:
                j = _pick_remove(ist[LADD], cost, score, stamp, sel, ist)
                remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
                           uncpos, ist, fst)
                ist[LREM] = j
            i = unc[np.int64((_rand(rng) >> np.uint64(11)) % np.uint64(ist[NUNC]))]
            k = _pick_add(i, ist[LREM], fst[BEST_COST] - tol - fst[COST], rptr, rcol, cost, score, stamp, ist)
            while ist[NSEL] > 0 and fst[COST] + cost[k] >= fst[BEST_COST] - tol:
                j = _pick_remove(ist[LADD], cost, score, stamp, sel, ist)
                remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
                           uncpos, ist, fst)
            add_col(k, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
                    ist, fst)
            ist[LADD] = k
        if need < 0:
            for t in range(ist[NUNC]):
                _bump(unc[t], rptr, rcol, pw, score, pinc[unc[t]], ist)
        elif ist[NUNC] > 0:
            _bump(unc[np.int64((_rand(rng) >> np.uint64(11)) % np.uint64(ist[NUNC]))], rptr, rcol, pw, score, 1.0,
                  ist)
    return 0


@numba.njit(**_JIT)
def _cc_touch(j, cptr, crow, rchg, clk):  # pragma: no cover - compiled
    """Configuration checking: column ``j`` changes state (event ``clk[0]``); every row of it
    records the event, which frees the columns sharing it (see :func:`_cc_ok`)."""
    clk[0] += 1
    for p in range(cptr[j], cptr[j + 1]):
        rchg[crow[p]] = clk[0]


@numba.njit(**_JIT)
def _cc_ok(c, cptr, crow, rchg, cblk, ist):  # pragma: no cover - compiled
    """True when column ``c`` may be added: never removed, or a column sharing a row with it
    changed state after its removal (event ``cblk[c]``)."""
    if cblk[c] == 0:
        return True
    ist[WORK] += cptr[c + 1] - cptr[c]
    for p in range(cptr[c], cptr[c + 1]):
        if rchg[crow[p]] > cblk[c]:
            cblk[c] = 0
            return True
    return False


@numba.njit(**_JIT)
def _rwls_remove(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
                 ist, fst, rchg, cblk, clk, ccmode, inc, pinc):  # pragma: no cover - compiled
    remove_col(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos, ist,
               fst, inc, pinc)
    if ccmode == 2:
        _cc_touch(j, cptr, crow, rchg, clk)
    clk[0] += 1
    cblk[j] = clk[0] if ccmode > 0 else 0


@numba.njit(**_JIT)
def search_rwls(cptr, crow, rptr, rcol, cost, roww, need, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
                best, ist, fst, rng, steps, target, stop_it, patience, rchg, cblk, clk, ccmode, wmode,
                pinc, restart):  # pragma: no cover - compiled
    """RWLS (Gao, Weise and Li 2015) for unit costs and full covers, ``steps`` iterations.

    One iteration: while S is a cover, it is recorded and its column of highest score (least loss;
    ties: unchanged for longest) removed. Then the column of S of highest score other than the one
    just added is removed, a random uncovered row drawn and its column of highest score that
    configuration checking allows (ties: unchanged for longest; the best one anyway if all are
    blocked) added. Configuration checking (``ccmode`` 1, or 2 to free on removals too): a
    removed column may not be added back until a column sharing a row with it is added (or, with
    2, removed); kept lazily as the last event of every row (``rchg``, (m,) int64)
    and the removal event of every column (``cblk``, (n,) int64, 0: free), ``clk`` (1,) int64
    the event counter; ``ccmode`` 0: only the column just removed may not be added back (tabu).
    Penalties (``wmode``): 0 (RWLS) raise every uncovered row after the
    move; 1 raise the rows the removed column leaves uncovered, before the addition; 2 as 1, and
    also after the removals from a cover (fontanf/setcoveringsolver's row weighting 1). Row ``i``
    rises by ``pinc[i]`` (1, or more for rows few columns cover).

    Returns
    -------
    int
        As :func:`search`.
    """
    for _ in range(steps):
        why = _stop(ist, fst, target, stop_it, patience, restart)
        if why:
            return why
        ist[IT] += 1
        while ist[NUNC] == 0:
            _record(x, best, cov, roww, need, ist, fst)
            if ist[NSEL] == 0 or fst[BEST_COST] <= target:
                return 1
            j = _pick_remove(-1, cost, score, stamp, sel, ist)
            _rwls_remove(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
                         uncpos, ist, fst, rchg, cblk, clk, ccmode, 1.0 if wmode == 2 else 0.0, pinc)
        if ist[NSEL] > 1:
            j = _pick_remove(ist[LADD], cost, score, stamp, sel, ist)
            _rwls_remove(j, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc,
                         uncpos, ist, fst, rchg, cblk, clk, ccmode, 1.0 if wmode >= 1 else 0.0, pinc)
            ist[LREM] = j
        i = unc[np.int64((_rand(rng) >> np.uint64(11)) % np.uint64(ist[NUNC]))]
        ist[WORK] += rptr[i + 1] - rptr[i]
        tabu = ist[LREM] if ccmode == 0 and rptr[i + 1] - rptr[i] > 1 else -1
        k = -1
        for q in range(rptr[i], rptr[i + 1]):
            c = rcol[q]
            if c == tabu:
                continue
            if k >= 0 and (score[c] < score[k] or (score[c] == score[k] and stamp[c] >= stamp[k])):
                continue
            if _cc_ok(c, cptr, crow, rchg, cblk, ist):
                k = c
        if k < 0:  # every column of the row is blocked: the oldest one of highest score
            for q in range(rptr[i], rptr[i + 1]):
                c = rcol[q]
                if k < 0 or score[c] > score[k] or (score[c] == score[k] and stamp[c] < stamp[k]):
                    k = c
        add_col(k, cptr, crow, rptr, rcol, cost, roww, x, cov, csum, pw, score, stamp, sel, selpos, unc, uncpos,
                ist, fst)
        _cc_touch(k, cptr, crow, rchg, clk)
        cblk[k] = 0
        ist[LADD] = k
        if wmode == 0:
            for t in range(ist[NUNC]):
                _bump(unc[t], rptr, rcol, pw, score, pinc[unc[t]], ist)
    return 0


# ----------------------------------------------------------------------------------------------
# Lagrangian lower bound
# ----------------------------------------------------------------------------------------------


# lst slots: step factor, best L, its magnitude, iterations without improvement
LAM, LBEST, LMAG, LSTALL = 0, 1, 2, 3
N_LST = 4


@numba.njit(**_JIT)
def lagrangian(cptr, crow, rptr, cost, roww, need, u, best_u, lst, iters, ub, patience):  # pragma: no cover - compiled
    """Subgradient optimisation of the Lagrangian relaxation of the covering rows (resumable:
    the multipliers ``u``, the best ones ``best_u`` and ``lst`` carry the state between calls).

    Full cover (``need < 0``): ``L(u) = sum_i u_i + sum_j min(0, c_j - sum_{i in j} u_i)``.
    Partial cover: the rows ``y_i <= sum_{j covers i} x_j`` are relaxed, and the ``y`` part
    ``min {u . y : y in [0, 1]^m, roww . y >= need}`` is a fractional knapsack (rows by increasing
    ``u_i / roww_i``). Every ``u >= 0`` gives a valid lower bound ``L(u)``.

    Step ``t = lam (ub - L) / |g|^2`` (Held and Karp; Beasley 1990), ``lam`` halved after
    ``patience`` iterations without improvement.

    Returns
    -------
    int
        Iterations run; -1 if converged (``lam`` below 1e-4, or a zero subgradient: ``L`` is then
        the optimum of the relaxation).
    """
    n = cptr.shape[0] - 1
    m = rptr.shape[0] - 1
    rc = np.empty(n)
    g = np.empty(m)
    y = np.zeros(m)
    ratio = np.empty(m)
    for it in range(iters):
        for j in range(n):
            s = cost[j]
            for p in range(cptr[j], cptr[j + 1]):
                s -= u[crow[p]]
            rc[j] = s
        val = 0.0
        mag = 0.0
        for j in range(n):
            if rc[j] < 0:
                val += rc[j]
                mag += abs(rc[j]) + cost[j]
        if need < 0:
            for i in range(m):
                val += u[i]
                mag += u[i]
                g[i] = 1.0
        else:
            for i in range(m):
                ratio[i] = u[i] / roww[i] if roww[i] > 0 else np.inf
                y[i] = 0.0
            order = np.argsort(ratio, kind="mergesort")
            left = need
            for t in range(m):
                i = order[t]
                if left <= 0 or roww[i] <= 0:
                    break
                take = min(1.0, left / roww[i])
                y[i] = take
                left -= take * roww[i]
                val += take * u[i]
                mag += take * u[i]
            for i in range(m):
                g[i] = y[i]
        for j in range(n):
            if rc[j] < 0:
                for p in range(cptr[j], cptr[j + 1]):
                    g[crow[p]] -= 1.0
        if val > lst[LBEST] + 1e-12 * abs(lst[LBEST]) + 1e-15:
            lst[LBEST] = val
            lst[LMAG] = mag
            best_u[:] = u
            lst[LSTALL] = 0.0
        else:
            lst[LSTALL] += 1.0
            if lst[LSTALL] >= patience:
                lst[LAM] *= 0.5
                lst[LSTALL] = 0.0
                if lst[LAM] < 1e-4:
                    return -1
        norm = 0.0
        for i in range(m):
            if u[i] <= 0 and g[i] < 0:
                g[i] = 0.0
            norm += g[i] * g[i]
        if norm <= 0:
            return -1
        t = lst[LAM] * max(ub - val, 1e-9 * (abs(ub) + 1.0)) / norm
        for i in range(m):
            v = u[i] + t * g[i]
            u[i] = v if v > 0 else 0.0
    return iters


# ----------------------------------------------------------------------------------------------
# exact test for a small unicost cover
# ----------------------------------------------------------------------------------------------


@numba.njit(**_JIT)
def column_bitsets(cptr, crow, m):  # pragma: no cover - compiled
    """(n, ceil(m / 64)) uint64 column bitsets of the column-major lists."""
    n = cptr.shape[0] - 1
    out = np.zeros((n, max(1, (m + 63) // 64)), dtype=np.uint64)
    for j in range(n):
        for p in range(cptr[j], cptr[j + 1]):
            i = crow[p]
            out[j, i >> 6] |= np.uint64(1) << np.uint64(i & 63)
    return out


@numba.njit(**_JIT)
def small_cover(cb, rptr, rcol, unc, level, k_left, banned, chosen, work, max_work):  # pragma: no cover - compiled
    """Depth-first search for a cover of the rows ``unc[level]`` (bitset) by at most ``k_left`` more
    columns of column bitsets ``cb`` (not ``banned``: (n,) int64, 0 or the level + 1 that banned it).

    Branches on the columns (in list order) of the uncovered row with the fewest columns (the first
    such row); a column explored at a node is banned in its later siblings' subtrees (the covers
    holding it were all seen); a node is cut when ``k_left`` times the most uncovered rows one column
    covers is below the uncovered rows. ``work`` [1] int64 counts word operations; past
    ``max_work`` the search gives up. Deterministic.

    Returns
    -------
    int
        1: a cover found (its columns in ``chosen[:level']``, -1 past its end); 0: none with at most
        ``k_left`` columns; -1: the work budget ran out.
    """
    n, n_words = cb.shape
    cnt = np.int64(0)
    best_r = np.int64(-1)
    best_d = np.int64(1) << 62
    for wd in range(n_words):
        x = unc[level, wd]
        cnt += np.int64(_popc(x))
        while x:
            r = (np.int64(wd) << 6) + np.int64(_ctz(x))
            x &= x - np.uint64(1)
            d = rptr[r + 1] - rptr[r]
            if d < best_d:
                best_d = d
                best_r = r
    work[0] += n_words
    if cnt == 0:
        for t in range(level, chosen.shape[0]):
            chosen[t] = -1
        return 1
    if k_left == 0:
        return 0
    if work[0] > max_work:
        return -1
    if k_left == 1:
        for p in range(rptr[best_r], rptr[best_r + 1]):
            j = rcol[p]
            if banned[j]:
                continue
            ok = True
            for wd in range(n_words):
                work[0] += 1
                if unc[level, wd] & ~cb[j, wd]:
                    ok = False
                    break
            if ok:
                chosen[level] = j
                for t in range(level + 1, chosen.shape[0]):
                    chosen[t] = -1
                return 1
        return 0
    most = np.int64(0)
    for j in range(n):
        if banned[j]:
            continue
        g = np.int64(0)
        for wd in range(n_words):
            g += np.int64(_popc(unc[level, wd] & cb[j, wd]))
        if g > most:
            most = g
    work[0] += n * n_words
    if most * k_left < cnt:
        return 0
    res = 0
    for p in range(rptr[best_r], rptr[best_r + 1]):
        j = rcol[p]
        if banned[j]:
            continue
        for wd in range(n_words):
            unc[level + 1, wd] = unc[level, wd] & ~cb[j, wd]
        work[0] += n_words
        chosen[level] = j
        res = small_cover(cb, rptr, rcol, unc, level + 1, k_left - 1, banned, chosen, work, max_work)
        if res != 0:
            break
        banned[j] = level + 1  # the covers holding j were all seen: not in the later siblings' subtrees
    for p in range(rptr[best_r], rptr[best_r + 1]):  # released for the parent's other branches
        if banned[rcol[p]] == level + 1:
            banned[rcol[p]] = 0
    return res
