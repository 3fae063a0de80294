"""Compiled (numba) bitset kernels of the bitset max-coverage engine (:mod:`camplace.solver.engines.bitset.search`).

A column is a row bitset: ``bits[c, w]`` holds rows ``64 w .. 64 w + 63`` of column ``c`` (bit
``r & 63`` of word ``r >> 6``). Every kernel is GIL-free.
"""

from __future__ import annotations

import numba
import numpy as np
from camplace._bitops import ctz as _ctz, popcount as _popcount

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}


@numba.njit(**_JIT)
def _bits_weight(x, wd, w):  # pragma: no cover - compiled
    """Sum of ``w[64 wd + t]`` over the set bits t of word ``x``."""
    acc = 0.0
    while x:
        acc += w[(wd << 6) + _ctz(x)]
        x &= x - np.uint64(1)
    return acc


@numba.njit(inline="always", **_JIT)
def _missed_weight(hit, wd, n_words, last_mask, planes, n_planes, w):  # pragma: no cover - compiled
    """Weight of the rows of word ``wd`` that ``hit`` misses (the last word masked to the real
    rows): popcounts over the weights' binary digits ``planes`` (B, n_words), or with
    ``n_planes = 0`` the set bits one by one."""
    x = ~hit
    if wd == n_words - 1:
        x &= last_mask
    if n_planes > 0:
        out = 0.0
        for b in range(n_planes):
            out += float(_popcount(x & planes[b, wd]) << np.uint64(b))
        return out
    return _bits_weight(x, wd, w)


@numba.njit(**_JIT)
def live_rows_block(lo, hi, indptr, data, w, live, cnt):  # pragma: no cover - compiled
    """:func:`live_rows` for rows ``lo .. hi - 1``, into ``live`` and ``cnt``."""
    for r in range(lo, hi):
        c = 0
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0:
                c += 1
        cnt[r] = c
        live[r] = c > 0 and w[r] > 0


@numba.njit(**_JIT)
def live_rows(indptr, indices, data, w):  # pragma: no cover - compiled
    """Rows with weight > 0 and at least one entry > 0; and each row's number of entries > 0.

    Returns
    -------
    live : (m,) bool
    row_nnz : (m,) int64
    """
    m = indptr.shape[0] - 1
    live = np.zeros(m, dtype=np.bool_)
    cnt = np.zeros(m, dtype=np.int64)
    live_rows_block(0, m, indptr, data, w, live, cnt)
    return live, cnt


@numba.njit(**_JIT)
def build_bits_block(lo, hi, indptr, indices, data, rows, col_map, out_t):  # pragma: no cover - compiled
    """Bits ``lo .. hi - 1`` (multiples of 64 but the last) of :func:`build_bits`, into the
    word-major ``out_t`` ((n_words, n_cols) uint64, zeroed)."""
    for i in range(lo, hi):
        r = rows[i]
        if r < 0:
            continue
        wd = i >> 6
        bit = np.uint64(1) << np.uint64(i & 63)
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0:
                c = col_map[indices[p]]
                if c >= 0:
                    out_t[wd, c] |= bit


@numba.njit(**_JIT)
def transpose_block(lo, hi, src, dst):  # pragma: no cover - compiled
    """``dst[c, :] = src[:, c]`` for columns ``c`` in ``lo .. hi - 1``."""
    for wd in range(src.shape[0]):
        for c in range(lo, hi):
            dst[c, wd] = src[wd, c]


@numba.njit(**_JIT)
def build_bits(indptr, indices, data, rows, col_map, n_cols):  # pragma: no cover - compiled
    """Column bitsets of the rows ``rows`` (bit ``i`` = ``rows[i]``) and the mapped columns.

    Parameters
    ----------
    indptr, indices, data : CSR arrays of the (m, n) matrix
    rows : (m',) int64
        Rows in bit order (-1: an empty padding row).
    col_map : (n,) int64
        New index of each column, -1 to leave it out.
    n_cols : int
        Number of new columns.

    Returns
    -------
    (n_cols, ceil(m' / 64)) uint64
    """
    n_words = (rows.shape[0] + 63) // 64
    out_t = np.zeros((n_words, n_cols), dtype=np.uint64)  # word-major while building
    build_bits_block(0, rows.shape[0], indptr, indices, data, rows, col_map, out_t)
    return np.ascontiguousarray(out_t.T)


@numba.njit(**_JIT)
def column_sizes_block(lo, hi, bits, size):  # pragma: no cover - compiled
    """:func:`column_sizes` of columns ``lo .. hi - 1``, into ``size``."""
    n_words = bits.shape[1]
    for c in range(lo, hi):
        s = 0
        for wd in range(n_words):
            s += _popcount(bits[c, wd])
        size[c] = s


@numba.njit(**_JIT)
def column_sizes(bits):  # pragma: no cover - compiled
    """(n,) int64: set bits of every column."""
    size = np.zeros(bits.shape[0], dtype=np.int64)
    column_sizes_block(0, bits.shape[0], bits, size)
    return size


@numba.njit(**_JIT)
def dominated_block(lo, hi, bits, size, row_nnz, indptr, indices, data, rows, out):  # pragma: no cover - compiled
    """:func:`dominated_columns` for the non-empty columns ``lo .. hi - 1``, into ``out`` (empty
    columns are left to the caller)."""
    n_words = bits.shape[1]
    for a in range(lo, hi):
        if size[a] == 0:
            continue
        best = -1
        best_cnt = np.int64(1) << 62
        for wd in range(n_words):
            x = bits[a, wd]
            while x:
                t = _ctz(x)
                i = (wd << 6) + t
                if row_nnz[rows[i]] < best_cnt:
                    best_cnt = row_nnz[rows[i]]
                    best = i
                x &= x - np.uint64(1)
        r = rows[best]
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] <= 0:
                continue
            b = indices[p]
            if b == a or size[b] < size[a] or (size[b] == size[a] and b > a):
                continue
            ok = True
            for wd in range(n_words):
                if bits[a, wd] & ~bits[b, wd]:
                    ok = False
                    break
            if ok:
                out[a] = True
                break


@numba.njit(**_JIT)
def dominated_empty(size, out):  # pragma: no cover - compiled
    """:func:`dominated_columns` for the empty columns: all but the first, or all when some
    column is non-empty."""
    first_empty = -1
    any_nonempty = False
    for c in range(size.shape[0]):
        if size[c] > 0:
            any_nonempty = True
        elif first_empty < 0:
            first_empty = c
    for a in range(size.shape[0]):
        if size[a] == 0:
            out[a] = any_nonempty or a != first_empty


@numba.njit(**_JIT)
def dominated_columns(bits, size, row_nnz, indptr, indices, data, rows):  # pragma: no cover - compiled
    """Columns whose row set is inside another column's (more rows, or identical and a lower index).

    Candidate dominators of column ``a`` are the columns observing ``a``'s rarest row, read from
    the CSR row (``rows[i]`` is the matrix row of bit ``i``); each is tested word by word.

    Returns
    -------
    (n,) bool
    """
    out = np.zeros(bits.shape[0], dtype=np.bool_)
    dominated_empty(size, out)
    dominated_block(0, bits.shape[0], bits, size, row_nnz, indptr, indices, data, rows, out)
    return out


@numba.njit(**_JIT)
def row_hashes_block(lo, hi, indptr, indices, data, rows, col_map, salt, h, has):  # pragma: no cover - compiled
    """:func:`row_hashes` of entries ``lo .. hi - 1`` of ``rows``, into ``h`` and ``has``."""
    for i in range(lo, hi):
        r = rows[i]
        acc = np.uint64(0)
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0:
                c = col_map[indices[p]]
                if c >= 0:
                    acc += salt[c]
                    has[i] = True
        h[i] = acc


@numba.njit(**_JIT)
def row_hashes(indptr, indices, data, rows, col_map, salt):  # pragma: no cover - compiled
    """64-bit hash of each row's set of mapped columns (sum of per-column random salts), and
    whether the row has any mapped column."""
    h = np.zeros(rows.shape[0], dtype=np.uint64)
    has = np.zeros(rows.shape[0], dtype=np.bool_)
    row_hashes_block(0, rows.shape[0], indptr, indices, data, rows, col_map, salt, h, has)
    return h, has


@numba.njit(**_JIT)
def _same_row(indptr, indices, data, col_map, r1, r2):  # pragma: no cover - compiled
    """True if rows r1 and r2 have the same set of mapped columns (CSR indices sorted)."""
    p1, e1 = indptr[r1], indptr[r1 + 1]
    p2, e2 = indptr[r2], indptr[r2 + 1]
    while True:
        while p1 < e1 and (data[p1] <= 0 or col_map[indices[p1]] < 0):
            p1 += 1
        while p2 < e2 and (data[p2] <= 0 or col_map[indices[p2]] < 0):
            p2 += 1
        if p1 == e1 or p2 == e2:
            return p1 == e1 and p2 == e2
        if indices[p1] != indices[p2]:
            return False
        p1 += 1
        p2 += 1


@numba.njit(**_JIT)
def renumber_by_first(groups, n_groups):  # pragma: no cover - compiled
    """Renumber ``groups`` ((m,) int64, values in ``0 .. n_groups - 1``) in place by first
    occurrence (the group of entry 0 becomes 0, the next new group 1, ...); returns
    ``(groups, n_groups)``."""
    new = np.full(n_groups, -1, dtype=np.int64)
    nxt = 0
    for i in range(groups.shape[0]):
        g = groups[i]
        if new[g] < 0:
            new[g] = nxt
            nxt += 1
        groups[i] = new[g]
    return groups, n_groups


@numba.njit(**_JIT)
def group_rows(indptr, indices, data, rows, col_map, h):  # pragma: no cover - compiled
    """Group rows with identical mapped column sets (hash buckets, then exact comparison).

    Returns
    -------
    groups : (m',) int64
        Group of each entry of ``rows``; groups are numbered by first occurrence.
    n_groups : int
    """
    m = rows.shape[0]
    order = np.argsort(h, kind="mergesort")
    groups = np.full(m, -1, dtype=np.int64)
    rep = np.empty(m, dtype=np.int64)  # representative entry of each provisional group
    n_groups = 0
    s = 0
    while s < m:
        e = s + 1
        while e < m and h[order[e]] == h[order[s]]:
            e += 1
        # bucket order[s:e]: split by exact comparison (collisions are very rare)
        g0 = n_groups
        for q in range(s, e):
            i = order[q]
            found = -1
            for g in range(g0, n_groups):
                if _same_row(indptr, indices, data, col_map, rows[rep[g]], rows[i]):
                    found = g
                    break
            if found < 0:
                found = n_groups
                rep[found] = i
                n_groups += 1
            groups[i] = found
        s = e
    return renumber_by_first(groups, n_groups)


@numba.njit(**_JIT)
def group_rows_block(q0, q1, order, hs, indptr, indices, data, rows, col_map, local, rep):  # pragma: no cover - compiled
    """:func:`group_rows`'s exact comparison for the hash-sorted positions ``q0 .. q1 - 1`` (whole
    buckets of equal ``hs``): ``local[q]`` receives the group of ``order[q]`` within its bucket,
    numbered as :func:`group_rows` numbers them (``rep``: (m',) int64 scratch, used at the
    bucket's own positions)."""
    s = q0
    while s < q1:
        e = s + 1
        while e < q1 and hs[e] == hs[s]:
            e += 1
        ng = 0
        for q in range(s, e):
            i = order[q]
            found = -1
            for g in range(ng):
                if _same_row(indptr, indices, data, col_map, rows[rep[s + g]], rows[i]):
                    found = g
                    break
            if found < 0:
                found = ng
                rep[s + ng] = i
                ng += 1
            local[q] = found
        s = e


@numba.njit(**_JIT)
def group_rows_finish(order, hs, local):  # pragma: no cover - compiled
    """:func:`group_rows`'s groups from the per-bucket numbers of :func:`group_rows_block`:
    buckets in hash order, then renumbered by first occurrence (the same output)."""
    m = order.shape[0]
    groups = np.full(m, -1, dtype=np.int64)
    n_groups = 0
    s = 0
    while s < m:
        e = s + 1
        top = local[s]
        while e < m and hs[e] == hs[s]:
            top = max(top, local[e])
            e += 1
        for q in range(s, e):
            groups[order[q]] = n_groups + local[q]
        n_groups += top + 1
        s = e
    return renumber_by_first(groups, n_groups)


@numba.njit(**_JIT)
def bisection_order(bits):  # pragma: no cover - compiled
    """Column order from recursive balanced bisection on the Hamming distance of the bitsets.

    A range of size s splits into its first s // 2 and last s - s // 2 positions (the tree of
    :func:`build_tree`); each split separates the columns nearer one far pivot from those nearer
    another (:func:`bisection_order_with` without coordinates).
    """
    return bisection_order_with(bits, np.zeros((bits.shape[0], 0), dtype=np.int64))


@numba.njit(**_JIT)
def bisection_order_with(bits, extra):  # pragma: no cover - compiled
    """:func:`bisection_order` of the bitsets with integer coordinates ``extra`` (n, d) int64 (>= 0)
    appended as thermometer codes, without making them: the Hamming distance of two columns grows
    by the L1 distance of their coordinates and a column's size by their sum, so the order is the
    one :func:`bisection_order` gives on the bitsets with those codes appended (a run of
    ``extra[c, j]`` ones per coordinate), at no memory and O(d) a distance."""
    n, n_words = bits.shape
    n_extra = extra.shape[1]
    perm = np.arange(n, dtype=np.int64)
    size = column_sizes(bits)
    for c in range(n):
        for j in range(n_extra):
            size[c] += extra[c, j]
    stack_lo = np.empty(128, dtype=np.int64)
    stack_hi = np.empty(128, dtype=np.int64)
    stack_lo[0] = 0
    stack_hi[0] = n
    sp = 1
    dist = np.empty(n, dtype=np.int64)
    key = np.empty(n, dtype=np.int64)
    while sp > 0:
        sp -= 1
        lo = stack_lo[sp]
        hi = stack_hi[sp]
        s = hi - lo
        if s <= 2:
            if s == 2 and size[perm[lo + 1]] > size[perm[lo]]:
                t = perm[lo]
                perm[lo] = perm[lo + 1]
                perm[lo + 1] = t
            continue
        # pivot 0: the largest column; pivot 1: farthest from it; pivot 2: farthest from pivot 1
        p0 = perm[lo]
        for q in range(lo, hi):
            if size[perm[q]] > size[p0]:
                p0 = perm[q]
        piv = p0
        p2 = p0
        for rep in range(2):
            far = -1
            fd = -1
            for q in range(lo, hi):
                c = perm[q]
                d = 0
                for wd in range(n_words):
                    d += _popcount(bits[c, wd] ^ bits[piv, wd])
                for j in range(n_extra):
                    d += abs(extra[c, j] - extra[piv, j])
                dist[q] = d
                if d > fd:
                    fd = d
                    far = c
            if rep == 0:
                piv = far
            else:
                p2 = far
        # key = d(c, p1) - d(c, p2): smaller is nearer p1 (dist holds d(c, p1) from the second pass)
        for q in range(lo, hi):
            c = perm[q]
            d2 = 0
            for wd in range(n_words):
                d2 += _popcount(bits[c, wd] ^ bits[p2, wd])
            for j in range(n_extra):
                d2 += abs(extra[c, j] - extra[p2, j])
            key[q] = dist[q] - d2
        idx = np.argsort(key[lo:hi], kind="mergesort")
        seg = perm[lo:hi].copy()
        for q in range(s):
            perm[lo + q] = seg[idx[q]]
        mid = lo + s // 2
        stack_lo[sp] = mid
        stack_hi[sp] = hi
        sp += 1
        stack_lo[sp] = lo
        stack_hi[sp] = mid
        sp += 1
    return perm


@numba.njit(**_JIT)
def tree_shape(n):  # pragma: no cover - compiled
    """Implicit bisection tree over ``n`` ordered columns, nodes numbered breadth-first.

    Node 0 is the root [0, n); a node [lo, hi) of size > 1 has children [lo, mid), [mid, hi)
    with ``mid = lo + (hi - lo) // 2`` (numbered after their parent). Leaves are single columns.

    Returns
    -------
    lo, hi, left, right : (2 n - 1,) int64 (left = right = -1 at leaves)
    """
    n_nodes = 2 * n - 1
    lo = np.empty(n_nodes, dtype=np.int64)
    hi = np.empty(n_nodes, dtype=np.int64)
    left = np.full(n_nodes, -1, dtype=np.int64)
    right = np.full(n_nodes, -1, dtype=np.int64)
    lo[0] = 0
    hi[0] = n
    nxt = 1
    for v in range(n_nodes):  # breadth-first creation: children always after parents
        if v >= nxt:
            break
        s = hi[v] - lo[v]
        if s > 1:
            mid = lo[v] + s // 2
            left[v] = nxt
            lo[nxt] = lo[v]
            hi[nxt] = mid
            right[v] = nxt + 1
            lo[nxt + 1] = mid
            hi[nxt + 1] = hi[v]
            nxt += 2
    return lo, hi, left, right


@numba.njit(**_JIT)
def build_tree(bits_ordered, n_levels):  # pragma: no cover - compiled
    """The tree of :func:`tree_shape` over the ordered columns with each node's level bitsets:
    ``levels[j - 1, v]`` holds the rows observed by at least ``j`` columns of node v (``j = 1``:
    the union).

    Returns
    -------
    lo, hi, left, right : (N,) int64 (left = right = -1 at leaves)
    levels : (n_levels, N, n_words) uint64
    """
    n, n_words = bits_ordered.shape
    n_nodes = 2 * n - 1
    lo, hi, left, right = tree_shape(n)
    levels = np.zeros((n_levels, n_nodes, n_words), dtype=np.uint64)
    for v in range(n_nodes - 1, -1, -1):
        if left[v] < 0:
            levels[0, v] = bits_ordered[lo[v]]
            continue
        a = left[v]
        b = right[v]
        for wd in range(n_words):
            for j in range(1, n_levels + 1):
                x = levels[j - 1, a, wd] | levels[j - 1, b, wd]
                for i in range(1, j):
                    x |= levels[i - 1, a, wd] & levels[j - i - 1, b, wd]
                levels[j - 1, v, wd] = x
    return lo, hi, left, right, levels


@numba.njit(inline="always", **_JIT)
def _two_of_three(l0, a, b, c, wd):  # pragma: no cover - compiled
    """Rows of word ``wd`` that at least two of the nodes ``a``, ``b``, ``c`` observe."""
    x = l0[a, wd]
    y = l0[b, wd]
    z = l0[c, wd]
    return (x & y) | (z & (x | y))


_COUNT_BLOCK = 16  # words summed between two checks of the early stop


@numba.njit(**_JIT)
def shortfall2_three(levels, a, b, c, planes, need, pw):  # pragma: no cover - compiled
    """:func:`shortfall` for two views and three distinct nodes ``a``, ``b``, ``c`` with integer
    weights (``planes`` (B, W) their binary digits, zero on padding rows, so no mask is needed):
    integer sums over blocks of ``_COUNT_BLOCK`` words without a branch per word, the early stop
    checked between blocks (about 2.7 times faster than the grouped counter on 783 words)."""
    l0 = levels[0]
    n_words = l0.shape[1]
    n_planes = planes.shape[0]
    total = np.uint64(0)
    wd = 0
    while wd < n_words:
        if pw <= wd < 2 * pw:
            wd = 2 * pw  # second rows of pairs: counted with their first rows
            continue
        hi = min(wd + _COUNT_BLOCK, pw if wd < pw else n_words)
        acc = np.uint64(0)
        if wd < pw:
            for v in range(wd, hi):
                x = ~(_two_of_three(l0, a, b, c, v) | _two_of_three(l0, a, b, c, v + pw))
                for p in range(n_planes):
                    acc += _popcount(x & planes[p, v]) << np.uint64(p)
        else:
            for v in range(wd, hi):
                x = ~_two_of_three(l0, a, b, c, v)
                for p in range(n_planes):
                    acc += _popcount(x & planes[p, v]) << np.uint64(p)
        total += acc
        if total >= need:
            return float(total)
        wd = hi
    return float(total)


@numba.njit(**_JIT)
def group_tuple(nodes, k, gnode, gcnt):  # pragma: no cover - compiled
    """Groups a non-decreasing tuple of ``k`` nodes: writes each distinct node to ``gnode`` and how
    often it occurs to ``gcnt`` ((k,) int64 each) and returns the number of groups."""
    ng = 0
    g = 0
    while g < k:
        v = nodes[g]
        c = 1
        while g + c < k and nodes[g + c] == v:
            c += 1
        gnode[ng] = v
        gcnt[ng] = c
        ng += 1
        g += c
    return ng


@numba.njit(inline="always", **_JIT)
def _two_views(levels, gnode, gcnt, ng, two_levels, ww):  # pragma: no cover - compiled
    """Rows of word ``ww`` that two cameras of the grouped tuple can observe (no angle)."""
    one = np.uint64(0)
    two = np.uint64(0)
    for a in range(ng):
        x = levels[0, gnode[a], ww]
        two |= one & x
        if two_levels and gcnt[a] >= 2:
            two |= levels[1, gnode[a], ww]
        one |= x
    return two


@numba.njit(**_JIT)
def shortfall2_grouped(levels, nodes, k, w, planes, last_mask, need, pw, gnode, gcnt):  # pragma: no cover - compiled
    """:func:`shortfall` for ``m = 2`` views: the tuple grouped once (``gnode``, ``gcnt``: (k,)
    int64 scratch), the counter unrolled (about four times faster than the general counter);
    three distinct nodes (k = 3; with k = 4 a repeated node's rows seen twice count too) with
    integer weights: :func:`shortfall2_three`."""
    ng = group_tuple(nodes, k, gnode, gcnt)
    if ng == 3 and k == 3 and planes.shape[0] > 0:
        return shortfall2_three(levels, gnode[0], gnode[1], gnode[2], planes, need, pw)
    two_levels = levels.shape[0] >= 2
    n_words = levels.shape[2]
    n_planes = planes.shape[0]
    total = 0.0
    for wd in range(n_words):
        if pw <= wd < 2 * pw:
            continue  # second rows of pairs: counted with their first rows
        hit = _two_views(levels, gnode, gcnt, ng, two_levels, wd)
        if wd < pw:
            hit |= _two_views(levels, gnode, gcnt, ng, two_levels, wd + pw)
        total += _missed_weight(hit, wd, n_words, last_mask, planes, n_planes, w)
        if total >= need:
            return total
    return total


@numba.njit(**_JIT)
def _shortfall3(levels, nodes, k, w, planes, last_mask, need, pw):  # pragma: no cover - compiled
    """:func:`shortfall` for ``m = 3`` views, with the counter unrolled (3.6 times faster on
    comet-67p-bunker, k = 6): a row reaches 3 views from 3 before, from 2 before and one column of a
    node, from 1 before and two of its columns (``L_2``), or from three of them (``L_3``)."""
    n_words = levels.shape[2]
    n_levels = levels.shape[0]
    n_planes = planes.shape[0]
    total = 0.0
    for wd in range(n_words):
        if pw <= wd < 2 * pw:
            continue  # second rows of pairs: counted with their first rows
        hit = np.uint64(0)
        for ww in range(wd, wd + pw + 1, pw) if wd < pw else range(wd, wd + 1):
            one = np.uint64(0)
            two = np.uint64(0)
            three = np.uint64(0)
            g = 0
            while g < k:
                v = nodes[g]
                c = 1
                while g + c < k and nodes[g + c] == v:
                    c += 1
                g += c
                x = levels[0, v, ww]
                if c >= 2 and n_levels >= 2:
                    x2 = levels[1, v, ww]
                    three |= (two & x) | (one & x2)
                    if c >= 3 and n_levels >= 3:
                        three |= levels[2, v, ww]
                    two |= (one & x) | x2
                else:
                    three |= two & x
                    two |= one & x
                one |= x
            hit |= three
        total += _missed_weight(hit, wd, n_words, last_mask, planes, n_planes, w)
        if total >= need:
            return total
    return total


_NO_FIXED = np.zeros((0, 1), dtype=np.uint64)  # no fixed columns (shortfall_fixed's fbits)


@numba.njit(**_JIT)
def shortfall(levels, nodes, k, m, w, planes, last_mask, need, acc, pw):  # pragma: no cover - compiled
    """Weight of the rows that fewer than ``m`` columns of the node tuple can observe.

    ``nodes`` (non-decreasing) holds k tree nodes, a node repeated c times standing for c
    distinct columns of it; such a group can give a row at most ``j`` views where the row is in
    ``levels[j - 1, node]`` (``j <= c``). The sum stops once it reaches ``need``.
    With integer weights, ``planes`` (B, n_words) holds their binary digits (``w_r = sum_b 2^b
    bit r of planes[b]``) and the sum is taken with popcounts; with ``B = 0`` the set bits are
    visited one by one. ``acc`` is (m + 1,) uint64 scratch.
    ``pw > 0`` is the opposite-pairs layout (:mod:`camplace.solver.engines.bitset.pair_cap`): row ``r`` of the
    first ``64 pw`` rows and row ``r + 64 pw`` are a pair of which at most one can count, carrying
    one weight (on the first row); the pair misses only when both rows miss.
    """
    if m == 2:
        if k == 3 and planes.shape[0] > 0 and nodes[0] != nodes[1] and nodes[1] != nodes[2]:
            return shortfall2_three(levels, nodes[0], nodes[1], nodes[2], planes, need, pw)  # no scratch needed
        return shortfall2_grouped(levels, nodes, k, w, planes, last_mask, need, pw, np.empty(k, dtype=np.int64),
                                  np.empty(k, dtype=np.int64))
    if m == 3:
        return _shortfall3(levels, nodes, k, w, planes, last_mask, need, pw)
    n_words = levels.shape[2]
    total = 0.0
    if m == 1 and planes.shape[0] == 0 and pw == 0:
        for wd in range(n_words):
            x = levels[0, nodes[0], wd]
            for j in range(1, k):
                x |= levels[0, nodes[j], wd]
            x = ~x
            if wd == n_words - 1:
                x &= last_mask
            total += _bits_weight(x, wd, w)
            if total >= need:
                return total
        return total
    return shortfall_fixed(levels, nodes, k, m, _NO_FIXED, w, planes, last_mask, need, acc, pw)


@numba.njit(**_JIT)
def shortfall_fixed(levels, nodes, k, m, fbits, w, planes, last_mask, need, acc, pw):  # pragma: no cover - compiled
    """:func:`shortfall` with fixed columns: ``fbits`` (r, n_words) uint64 holds the bitsets of r
    columns that are part of every set (r = 0: none), each adding one view where it observes a
    row. The general bit-parallel counter (``acc`` (m + 1,) uint64 scratch), any ``m``."""
    n_words = levels.shape[2]
    n_levels = levels.shape[0]
    n_planes = planes.shape[0]
    r = fbits.shape[0]
    total = 0.0
    for wd in range(n_words):
        if pw <= wd < 2 * pw:
            continue  # second rows of pairs: counted with their first rows
        hit = np.uint64(0)
        for ww in range(wd, wd + pw + 1, pw) if wd < pw else range(wd, wd + 1):
            acc[0] = ~np.uint64(0)
            for t in range(1, m + 1):
                acc[t] = 0
            g = 0
            while g < k:
                v = nodes[g]
                c = 1
                while g + c < k and nodes[g + c] == v:
                    c += 1
                g += c
                cm = min(c, n_levels)
                for t in range(m, 0, -1):
                    add = np.uint64(0)
                    for j in range(1, min(cm, t) + 1):
                        add |= acc[t - j] & levels[j - 1, v, ww]
                    acc[t] |= add
            for f in range(r):
                y = fbits[f, ww]
                for t in range(m, 0, -1):
                    acc[t] |= acc[t - 1] & y
            hit |= acc[m]
        total += _missed_weight(hit, wd, n_words, last_mask, planes, n_planes, w)
        if total >= need:
            return total
    return total


@numba.njit(**_JIT)
def selection_levels(sel_bits, m, n_words):  # pragma: no cover - compiled
    """Per word the rows in at least ``m`` (``done``) and ``m - 1`` (``near``) of ``sel_bits``."""
    ks = sel_bits.shape[0]
    near = np.zeros(n_words, dtype=np.uint64)
    done = np.zeros(n_words, dtype=np.uint64)
    acc = np.zeros(m + 1, dtype=np.uint64)
    for wd in range(n_words):
        for t in range(m + 1):
            acc[t] = 0
        acc[0] = ~np.uint64(0)
        for j in range(ks):
            y = sel_bits[j, wd]
            for t in range(m, 0, -1):
                acc[t] |= acc[t - 1] & y
        done[wd] = acc[m]
        near[wd] = acc[m - 1]
    return done, near


@numba.njit(**_JIT)
def shortfall_all_block(lo, hi, bits, done, near, w, last_mask, out):  # pragma: no cover - compiled
    """:func:`shortfall_all` of columns ``lo .. hi - 1`` (``done``, ``near``: :func:`selection_levels`)."""
    n_words = bits.shape[1]
    for c in range(lo, hi):
        tot = 0.0
        for wd in range(n_words):
            x = ~(done[wd] | (near[wd] & bits[c, wd]))
            if wd == n_words - 1:
                x &= last_mask
            tot += _bits_weight(x, wd, w)
        out[c] = tot


@numba.njit(**_JIT)
def shortfall_all(bits, sel_bits, m, w, last_mask):  # pragma: no cover - compiled
    """For every column x: weight of the rows in fewer than ``m`` of ``sel_bits`` rows plus x."""
    done, near = selection_levels(sel_bits, m, bits.shape[1])
    out = np.zeros(bits.shape[0], dtype=np.float64)
    shortfall_all_block(0, bits.shape[0], bits, done, near, w, last_mask, out)
    return out


@numba.njit(**_JIT)
def all_leaves(tup, lo, hi):  # pragma: no cover - compiled
    """True if every node of the tuple is a single column (the tuple is one camera set)."""
    for j in range(tup.shape[0]):
        if hi[tup[j]] - lo[tup[j]] > 1:
            return False
    return True


@numba.njit(**_JIT)
def _split_at(cur, jbest, lo, hi, left, right, out, sort):  # pragma: no cover - compiled
    """The children of ``cur`` when the node at position ``jbest`` (-1: none) is split: the
    positions that node holds get every mix of its children L and R (a leaf never twice, a node
    never more often than it has columns); ``sort`` sorts each child (equal nodes adjacent).
    Writes them to ``out`` ((k + 1, k) int64) and returns their number."""
    if jbest < 0:
        return 0
    k = cur.shape[0]
    v = cur[jbest]
    first = jbest
    while first > 0 and cur[first - 1] == v:
        first -= 1
    last = jbest
    while last < k - 1 and cur[last + 1] == v:
        last += 1
    cnt = last - first + 1
    lch = left[v]
    rch = right[v]
    n_out = 0
    for nl in range(cnt, -1, -1):  # nl copies of L, then cnt - nl copies of R
        nr = cnt - nl
        if nl > hi[lch] - lo[lch] or nr > hi[rch] - lo[rch]:
            continue
        for j in range(k):
            out[n_out, j] = cur[j]
        for j in range(cnt):
            out[n_out, first + j] = lch if j < nl else rch
        if sort:
            for i in range(1, k):  # insertion sort (k <= 8)
                x = out[n_out, i]
                j = i - 1
                while j >= 0 and out[n_out, j] > x:
                    out[n_out, j + 1] = out[n_out, j]
                    j -= 1
                out[n_out, j + 1] = x
        n_out += 1
    return n_out


@numba.njit(**_JIT)
def split_tuple(cur, lo, hi, left, right, out):  # pragma: no cover - compiled
    """Children of a non-decreasing tuple of tree nodes: its largest node v is split into its
    children L < R and the positions v holds are replaced by every non-decreasing mix of L and R
    (a leaf never twice, a node never more often than it has columns).

    Writes the children to ``out`` ((k + 1, k) int64) and returns their number (0 for a tuple
    of leaves).
    """
    k = cur.shape[0]
    jbest = -1
    sbest = 1
    for j in range(k):
        s = hi[cur[j]] - lo[cur[j]]
        if s > sbest:
            sbest = s
            jbest = j
    return _split_at(cur, jbest, lo, hi, left, right, out, False)


@numba.njit(**_JIT)
def union_weights(bits, w, planes):  # pragma: no cover - compiled
    """(N,) float64: the weight of the rows set in each bitset of ``bits`` (N, n_words) (popcounts
    over ``planes`` when it has rows, else the set bits one by one)."""
    n, n_words = bits.shape
    n_planes = planes.shape[0]
    out = np.zeros(n)
    for v in range(n):
        acc = 0.0
        for wd in range(n_words):
            x = bits[v, wd]
            if n_planes > 0:
                for b in range(n_planes):
                    acc += float(_popcount(x & planes[b, wd]) << np.uint64(b))
            else:
                acc += _bits_weight(x, wd, w)
        out[v] = acc
    return out


@numba.njit(**_JIT)
def split_tuple_by(cur, score, lo, hi, left, right, out):  # pragma: no cover - compiled
    """:func:`split_tuple` splitting, among the nodes of two or more columns, the one of largest
    ``score`` ((N,) float64; ties: the first) instead of the largest node; each child is sorted
    (equal nodes adjacent). Any choice keeps every column set in exactly one child."""
    k = cur.shape[0]
    jbest = -1
    sbest = -np.inf
    for j in range(k):
        v = cur[j]
        if hi[v] - lo[v] > 1 and score[v] > sbest:
            sbest = score[v]
            jbest = j
    return _split_at(cur, jbest, lo, hi, left, right, out, True)


@numba.njit(**_JIT)
def child_bound(levels, child, m, w, planes, last_mask, total, beat, colmax, acc, pw):  # pragma: no cover - compiled
    """Bound of a node tuple: ``total - shortfall``, also at most ``sum_t colmax[v_t] / m`` when
    ``colmax`` is given (a counted row is observed by ``m`` chosen columns). Returns ``-inf`` as
    soon as it is clear the bound cannot exceed ``beat`` (the column cap is checked first)."""
    k = child.shape[0]
    wcap = np.inf
    if colmax.shape[0] > 0:
        wcap = 0.0
        for j in range(k):
            wcap += colmax[child[j]]
        wcap /= m
        if wcap <= beat:
            return -np.inf
    b = min(wcap, total - shortfall(levels, child, k, m, w, planes, last_mask, total - beat, acc, pw))
    return b if b > beat else -np.inf


@numba.njit(**_JIT)
def tuple_search(lo, hi, left, right, levels, m, w, planes, last_mask, total, margin, stack, stack_bound, sp, best, best_set,
                 budget, colmax, pw, score):  # pragma: no cover - compiled
    """Depth-first search over k-tuples of tree nodes with the union bound (resumable).

    A stack entry is a non-decreasing tuple of nodes (``stack[i, :k]``) standing for every k-subset
    of columns with one column in each node, and ``stack_bound[i]`` an upper bound on their
    values. The bound of a tuple is ``total - shortfall`` (see :func:`shortfall`); children come
    from :func:`split_tuple`.
    With ``m > 1`` and ``colmax`` (per node, the largest weight one of its columns observes) the
    bound is also at most ``sum_t colmax[v_t] / m``: a row that counts is observed by at least m
    chosen columns, so m times the value is at most the sum of their weights. That check comes
    first and skips the row scan when it already prunes. ``pw``: the opposite-pairs layout (see
    :func:`shortfall`; 0 for none). A non-empty ``score`` chooses the node to split
    (:func:`split_tuple_by`); otherwise the largest is split.
    A popped tuple whose bound cannot beat ``best`` (by more than ``margin``) is dropped;
    otherwise its largest node is split into its two children L < R, and the positions it holds
    are replaced by every non-decreasing mix of L and R (a leaf never twice, a node never more
    often than it has columns). A child tuple of leaves is a k-subset: its bound is its exact value.

    Returns
    -------
    sp : int
        Stack size when the budget ran out (0: search complete; -1: stack overflow).
    best : float
        Incumbent value (``best_set`` receives the column positions of an improvement).
    evaluated : int
        Bounds computed.
    """
    k = stack.shape[1]
    cap = stack.shape[0]
    evaluated = 0
    kids = np.empty((k + 1, k), dtype=np.int64)
    cand = np.empty((k + 1, k), dtype=np.int64)
    cand_b = np.empty(k + 1, dtype=np.float64)
    used = np.zeros(k + 1, dtype=np.bool_)
    acc = np.zeros(m + 1, dtype=np.uint64)
    while sp > 0 and evaluated < budget:
        sp -= 1
        if stack_bound[sp] <= best + margin:
            continue
        if score.shape[0] > 0:
            n_kids = split_tuple_by(stack[sp], score, lo, hi, left, right, kids)
        else:
            n_kids = split_tuple(stack[sp], lo, hi, left, right, kids)
        nc = 0
        for c in range(n_kids):
            child = kids[c]
            evaluated += 1
            bnd = child_bound(levels, child, m, w, planes, last_mask, total, best + margin, colmax, acc, pw)
            if bnd <= best + margin:
                continue
            if all_leaves(child, lo, hi):
                best = bnd
                for j in range(k):
                    best_set[j] = lo[child[j]]
                continue
            for j in range(k):
                cand[nc, j] = child[j]
            cand_b[nc] = bnd
            used[nc] = False
            nc += 1
        # push in increasing bound order: the most promising child is popped first
        for _ in range(nc):
            jmin = -1
            for q in range(nc):
                if not used[q] and (jmin < 0 or cand_b[q] < cand_b[jmin]):
                    jmin = q
            if sp >= cap:
                return -1, best, evaluated
            for j in range(k):
                stack[sp, j] = cand[jmin, j]
            stack_bound[sp] = cand_b[jmin]
            used[jmin] = True
            sp += 1
    return sp, best, evaluated


@numba.njit(**_JIT)
def extract_rows(indptr, indices, data, rows, col_map):  # pragma: no cover - compiled
    """CSR pattern (indptr, int32 indices) of ``rows`` restricted to the mapped columns."""
    nnz = 0
    for i in range(rows.shape[0]):
        r = rows[i]
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0 and col_map[indices[p]] >= 0:
                nnz += 1
    out_ptr = np.zeros(rows.shape[0] + 1, dtype=np.int64)
    out_idx = np.empty(nnz, dtype=np.int32)
    q = 0
    for i in range(rows.shape[0]):
        r = rows[i]
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0:
                c = col_map[indices[p]]
                if c >= 0:
                    out_idx[q] = c
                    q += 1
        out_ptr[i + 1] = q
    return out_ptr, out_idx


@numba.njit(**_JIT)
def selected_row_stats_block(lo, hi, indptr, indices, data, chosen, count, vmax):  # pragma: no cover - compiled
    """:func:`selected_row_stats` of rows ``lo:hi``, written into ``count`` and ``vmax``."""
    for r in range(lo, hi):
        for p in range(indptr[r], indptr[r + 1]):
            if chosen[indices[p]]:
                v = data[p]
                if v > 0:
                    count[r] += 1
                    if v > vmax[r]:
                        vmax[r] = v


@numba.njit(**_JIT)
def selected_row_stats(indptr, indices, data, chosen):  # pragma: no cover - compiled
    """Per row: how many chosen columns have a value > 0 there, and the largest such value (on the
    pool: :func:`camplace.solver._support.parkernels.selected_row_stats`).

    Parameters
    ----------
    indptr, indices, data : CSR arrays of an (m, n) matrix
    chosen : (n,) bool

    Returns
    -------
    count : (m,) int64
    vmax : (m,) float64 (0 where no chosen column observes the row)
    """
    m = indptr.shape[0] - 1
    count = np.zeros(m, dtype=np.int64)
    vmax = np.zeros(m, dtype=np.float64)
    selected_row_stats_block(0, m, indptr, indices, data, chosen, count, vmax)
    return count, vmax


def weight_planes(counts: np.ndarray, max_planes: int = 24) -> np.ndarray:
    """Binary digits of non-negative integer weights as bit planes (B, ceil(m / 64)) uint64.

    Returns a (0, n_words) array when the weights are not integers or need more than
    ``max_planes`` digits.
    """
    m = counts.shape[0]
    n_words = (m + 63) // 64
    c = np.asarray(counts)
    if m == 0 or np.any(c != np.floor(c)) or np.any(c < 0) or float(c.max()) >= 2.0**max_planes:
        return np.zeros((0, n_words), dtype=np.uint64)
    ci = c.astype(np.int64)
    n_planes = max(1, int(ci.max()).bit_length())
    out = np.zeros((n_planes, n_words * 64), dtype=bool)
    for b in range(n_planes):
        out[b, :m] = (ci >> b) & 1
    return np.packbits(out.reshape(n_planes, n_words, 64), axis=2, bitorder="little").view(np.uint64).reshape(n_planes, n_words)


@numba.njit(**_JIT)
def row_bits(indptr, indices, data, rows, col_map, n_cols):  # pragma: no cover - compiled
    """Row bitsets of ``rows`` over the mapped columns (the transpose layout of :func:`build_bits`).

    Parameters
    ----------
    indptr, indices, data : CSR arrays of the (m, n) matrix
    rows : (m',) int64
        Rows to keep, in output order.
    col_map : (n,) int64
        Bit index of each column, -1 to leave it out.
    n_cols : int
        Number of mapped columns.

    Returns
    -------
    (m', ceil(n_cols / 64)) uint64
    """
    out = np.zeros((rows.shape[0], (n_cols + 63) // 64), dtype=np.uint64)
    for i in range(rows.shape[0]):
        r = rows[i]
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] > 0:
                c = col_map[indices[p]]
                if c >= 0:
                    out[i, c >> 6] |= np.uint64(1) << np.uint64(c & 63)
    return out


@numba.njit(**_JIT)
def _unlink(i, nxt, prv, head):  # pragma: no cover - compiled
    if prv[i] >= 0:
        nxt[prv[i]] = nxt[i]
    else:
        head[0] = nxt[i]
    if nxt[i] < nxt.shape[0]:
        prv[nxt[i]] = prv[i]


@numba.njit(**_JIT)
def opposite_matching(bits, rem, nxt, prv, alive, head, start, stop, pairs, amount, n_pairs):  # pragma: no cover - compiled
    """Greedy fractional matching of rows no column observes together, resumable.

    Rows are taken in positions ``start .. stop - 1``; each is paired with the earliest
    still-unexhausted later rows whose bitsets are disjoint from its own, moving
    ``min(rem[p], rem[q])`` of weight each time, until its weight is used up. ``rem``, ``nxt``,
    ``prv`` (a doubly linked list of the rows with weight left), ``alive`` and ``head`` (1,) carry
    the state from one call to the next. Every match exhausts one of its rows, so at most
    ``m'`` are made.

    Parameters
    ----------
    bits : (m', W) uint64
        Row bitsets, in processing order.
    rem : (m',) float64
        Weight not yet matched.
    pairs : (m', 2) int64, amount : (m',) float64, n_pairs : (1,) int64
        Receive the matches (row positions) and their weights; ``n_pairs`` counts them.

    Returns
    -------
    mass : float
        Weight matched in this call (each pair counted once).
    checks : int
        Pairs tested.
    """
    m = bits.shape[0]
    n_words = bits.shape[1]
    mass = 0.0
    checks = 0
    for p in range(start, stop):
        if not alive[p]:
            continue
        alive[p] = False
        _unlink(p, nxt, prv, head)
        q = head[0]
        while q < m and rem[p] > 0.0:
            checks += 1
            disjoint = True
            for wd in range(n_words):
                if bits[p, wd] & bits[q, wd]:
                    disjoint = False
                    break
            nq = nxt[q]
            if disjoint:
                f = min(rem[p], rem[q])
                rem[p] -= f
                rem[q] -= f
                mass += f
                i = n_pairs[0]
                pairs[i, 0] = p
                pairs[i, 1] = q
                amount[i] = f
                n_pairs[0] = i + 1
                if rem[q] <= 0.0:
                    alive[q] = False
                    _unlink(q, nxt, prv, head)
            q = nq
    return mass, checks
