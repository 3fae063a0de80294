"""The one-pass matrix summary against plain numpy, and the same bits at every thread count."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from camplace.visibility.summary import summarise


def _oracle(a: sp.csr_matrix, weights, selected, frame, fw, n_frames):
    dense = a.toarray() != 0
    useful = int(np.count_nonzero(dense[weights > 0].any(axis=0)))
    covered = dense[:, selected].any(axis=1) if len(selected) else np.zeros(a.shape[0], dtype=bool)
    seen = np.array([np.bincount(frame[dense[:, j]], weights=fw[dense[:, j]], minlength=n_frames) for j in selected])
    return useful, covered, seen.reshape(len(selected), n_frames)


@settings(max_examples=60, deadline=None)
@given(m=st.integers(1, 300), n=st.integers(1, 40), density=st.floats(0.0, 0.6), n_frames=st.integers(1, 4),
       seed=st.integers(0, 2**31 - 1), k=st.integers(0, 5))
def test_summary_matches_numpy(m, n, density, n_frames, seed, k):
    rng = np.random.default_rng(seed)
    a = sp.random(m, n, density=density, format="csr", random_state=rng, dtype=np.float32)
    a.data[:] = rng.random(a.nnz, dtype=np.float32) + 0.1
    weights = np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
    frame = rng.integers(0, n_frames, m)
    fw = rng.random(m)
    selected = list(rng.choice(n, size=min(k, n), replace=False))
    got = summarise(a, weights, selected, frame, fw, n_frames)
    useful, covered, seen = _oracle(a, weights, selected, frame, fw, n_frames)
    assert got.useful_columns == useful
    np.testing.assert_array_equal(got.covered, covered)
    np.testing.assert_allclose(got.seen, seen, rtol=1e-12, atol=0)


_BITS = """
import sys, numpy as np, scipy.sparse as sp
from camplace._cores import set_threads
import camplace.visibility.summary as S
set_threads(int(sys.argv[1]))
S.PARALLEL_MIN_NNZ = 0  # the thread pool even on this small matrix
summarise = S.summarise
rng = np.random.default_rng(5)
a = sp.random(20000, 300, density=0.2, format="csr", random_state=rng, dtype=np.float32)
w = rng.random(20000); f = rng.integers(0, 7, 20000)
s = summarise(a, w, [3, 77, 150, 299], f, w, 7)
sys.stdout.write(s.seen.tobytes().hex() + " " + str(s.useful_columns) + " " + s.covered.tobytes().hex()[:64])
"""


def test_summary_is_the_same_bits_on_one_and_two_threads():
    outs = set()
    for threads in ("1", "2"):
        proc = subprocess.run([sys.executable, "-c", _BITS, threads], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        outs.add(proc.stdout)
    assert len(outs) == 1
