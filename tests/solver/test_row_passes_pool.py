"""The angle engine's per-row status and the selected columns' row counts on the block pool equal
the serial kernels (and a direct numpy count) bit for bit, at 1 and 2 threads (the selected
columns' counts also on 3 pool threads), on CSR and bits."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from camplace._cores import using_threads
from camplace.solver._support import bitkernels as K
from camplace.solver._support import parkernels as PK
from camplace.solver.engines.angle import _kernels as AK
from camplace.solver.engines.angle.search import _Rows
from camplace.visibility.bits import bits_from_csr


@pytest.fixture(scope="module")
def case():
    rng = np.random.default_rng(5)
    m, n = 300_000, 400  # over PARALLEL_MIN_WORK entries: the pool is used
    nnz = m * n // 100  # about 1 % of the cells (a repeated cell counts once)
    rows, cols = rng.integers(0, m, nnz), rng.integers(0, n, nnz)
    q = sp.csr_matrix((np.ones(nnz, dtype=bool), (rows, cols)), shape=(m, n))  # (sp.random takes 6 s here)
    q.sum_duplicates()
    q.sort_indices()
    pos = rng.random((n, 3)) * 10.0
    pts = rng.random((m, 3))
    sel = np.sort(rng.choice(n, 25, replace=False)).astype(np.int64)
    return q, pos, pts, sel


@pytest.mark.parametrize("threads", [1, 2])
def test_row_status_on_the_pool_equals_the_serial_kernel(case, threads: int) -> None:
    q, pos, pts, sel = case
    data = q.data.view(np.uint8)
    want = AK.row_status(q.indptr, q.indices, data, sel, pos, pts, 2, 25.0)
    assert int(want[1].sum()) > 1000 and int((want[0] >= 2).sum()) > int(want[1].sum())  # both outcomes occur
    with using_threads(threads):
        got_csr = _Rows(q).row_status(sel, pos, pts, 2, 25.0)
        got_bits = _Rows(bits_from_csr(q)).row_status(sel, pos, pts, 2, 25.0)
    for got in (got_csr, got_bits):
        for a, b in zip(want, got, strict=True):
            assert a.dtype == b.dtype and np.array_equal(a, b)
    assert np.array_equal(want[0], np.asarray(q[:, sel].sum(axis=1)).ravel())


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_selected_row_stats_on_the_pool_equals_the_serial_kernel(case, threads: int) -> None:
    q, _, _, sel = case
    vals = q.astype(np.float64)
    vals.data = np.random.default_rng(1).random(vals.nnz)
    chosen = np.zeros(q.shape[1], dtype=bool)
    chosen[sel] = True
    want = K.selected_row_stats(vals.indptr, vals.indices, vals.data, chosen)
    got = PK.selected_row_stats(vals.indptr, vals.indices, vals.data, chosen, threads=threads)
    for a, b in zip(want, got, strict=True):
        assert np.array_equal(a, b)
    assert np.array_equal(want[0], np.asarray((vals[:, sel] > 0).sum(axis=1)).ravel())
    assert np.array_equal(want[1], vals[:, sel].max(axis=1).toarray().ravel())
