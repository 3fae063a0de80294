"""A Dask cluster computes the identical matrix, even when a worker dies mid-computation."""

import os
import signal
import sys

import numpy as np
import pytest

from camplace.errors import CamplaceError
from camplace.instance import builtin
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, make_target_points
from camplace.visibility.distributed import compute_chunks_dask
from camplace.visibility.engine import assemble, compute_chunk, make_task


@pytest.fixture(scope="module")
def problem():
    inst = builtin("comet-67p-bunker")
    pts = make_target_points(inst, 3000, seed=1)
    cands = make_candidates("sobol", 240, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=2)
    local = compute_visibility(inst, cands, pts, chunk_size=16).matrix
    return inst, pts, cands, local


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed", reason="the test extra installs dask[distributed]")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        with distributed.Client(c) as client:
            yield client


def same(a, b) -> bool:
    return a.shape == b.shape and (a != b).nnz == 0 and np.array_equal(a.indptr, b.indptr)


@pytest.mark.slow
def test_local_cluster_matrix_is_identical(problem, cluster) -> None:
    inst, pts, cands, local = problem
    task, _ = make_task(inst, cands, pts)
    starts = list(range(0, len(cands), 16))
    parts = compute_chunks_dask(task, starts, 16, client=cluster)
    matrix, _ = assemble(task, parts)
    assert same(matrix, local)


@pytest.mark.slow
def test_worker_killed_midway_still_identical(problem, cluster) -> None:
    inst, pts, cands, local = problem
    task, _ = make_task(inst, cands, pts)
    starts = list(range(0, len(cands), 4))
    victim = sorted(cluster.scheduler_info()["workers"])[0]
    pid = cluster.run(os.getpid, workers=[victim])[victim]
    killed = []

    def kill_once(_n: int) -> None:
        if not killed:  # after the first finished chunk: SIGKILL one worker process
            killed.append(pid)
            os.kill(pid, signal.SIGKILL)

    parts = compute_chunks_dask(task, starts, 4, client=cluster, progress=kill_once)
    assert killed
    with pytest.raises(ProcessLookupError):  # that worker process is really gone
        os.kill(pid, 0)
    matrix, _ = assemble(task, parts)
    assert same(matrix, local)
    # the chunks were computed for real on the cluster: the victim is gone or was restarted
    cluster.wait_for_workers(2, timeout=60)


@pytest.mark.slow
def test_cli_dask_local_matches_in_process(problem) -> None:
    inst, pts, cands, local = problem
    m = compute_visibility(inst, cands, pts, chunk_size=16, dask_address="local:2").matrix
    assert same(m, local)


def test_missing_dask_gives_install_hint(problem, monkeypatch) -> None:
    inst, pts, cands, _ = problem
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(CamplaceError, match=r"pip install 'camplace\[dask\]'"):
        compute_visibility(inst, cands, pts, chunk_size=16, dask_address="local:2")


def test_chunks_are_independent_of_chunking(problem) -> None:
    inst, pts, cands, local = problem
    task, scenes = make_task(inst, cands, pts)
    parts = [compute_chunk(task, scenes, s, min(s + 7, len(cands))) for s in range(0, len(cands), 7)]
    assert same(assemble(task, parts)[0], local)


@pytest.mark.slow
def test_team_columns_on_a_cluster_are_identical() -> None:
    """A camera team (issue 31): chunks end at the model boundaries, each with its model's intrinsics."""
    pytest.importorskip("distributed", reason="the test extra installs dask[distributed]")
    from camplace.visibility.stages import make_run_candidates, stage_seeds

    inst = builtin("comet-67p-team")
    pts = make_target_points(inst, 1500, seed=1)
    cands = make_run_candidates(inst, "sobol", 60, 1, stage_seeds(2)[0])
    assert len(set(cands.model.tolist())) == 2 and np.count_nonzero(cands.model == 0) % 16 != 0  # a chunk would straddle
    local = compute_visibility(inst, cands, pts, chunk_size=16).matrix
    m = compute_visibility(inst, cands, pts, chunk_size=16, dask_address="local:2").matrix
    assert same(m, local) and local.nnz > 0


@pytest.mark.slow
def test_bits_from_a_cluster_equal_the_threaded_bits_with_a_worker_killed(problem, cluster) -> None:
    """Issue 32: workers hand back bit-packed column blocks; a killed worker's chunks are recomputed."""
    from camplace.visibility.bits import bit_words

    inst, pts, cands, local = problem
    ref = compute_visibility(inst, cands, pts, chunk_size=16)
    assert ref.bits is not None
    task, _ = make_task(inst, cands, pts)
    words = np.zeros((len(cands), bit_words(len(pts))), dtype=np.uint64)
    victim = sorted(cluster.scheduler_info()["workers"])[0]
    pid = cluster.run(os.getpid, workers=[victim])[victim]
    killed = []

    def kill_once(_n: int) -> None:
        if not killed:
            killed.append(pid)
            os.kill(pid, signal.SIGKILL)

    parts = compute_chunks_dask(task, list(range(0, len(cands), 8)), 8, client=cluster, progress=kill_once,
                                words=words)
    assert killed and all(len(p.lcols) == 0 for p in parts)  # no pair lists came back
    np.testing.assert_array_equal(words, ref.bits.words)
    assert sum(p.counts["observed"] for p in parts) == ref.stats["observed"]
    cluster.wait_for_workers(2, timeout=60)


@pytest.mark.slow
def test_dask_run_gives_the_same_bits(problem) -> None:
    inst, pts, cands, local = problem
    ref = compute_visibility(inst, cands, pts, chunk_size=16)
    got = compute_visibility(inst, cands, pts, chunk_size=16, dask_address="local:2")
    assert got.bits is not None and got._matrix is None
    np.testing.assert_array_equal(got.bits.words, ref.bits.words)
    assert got.stats == ref.stats


@pytest.mark.slow
def test_dask_run_gives_the_same_quantised_columns(problem) -> None:
    import dataclasses

    inst, pts, cands, _ = problem
    graded = dataclasses.replace(inst, quality=dataclasses.replace(inst.quality, mode="graded"))
    ref = compute_visibility(graded, cands, pts, chunk_size=16)
    got = compute_visibility(graded, cands, pts, chunk_size=16, dask_address="local:2")
    assert got.qbytes is not None and got._matrix is None and ref.qbytes is not None
    assert ref.qbytes.nnz > 0 and np.unique(ref.qbytes.values).size > 100  # really graded
    np.testing.assert_array_equal(got.qbytes.values, ref.qbytes.values)
    assert got.stats == ref.stats


def test_a_worker_hands_back_byte_columns_not_pairs(problem) -> None:
    """The worker entry of a graded run returns its chunk's quantised columns (one byte a cell),
    equal to the in-process matrix's, for a chunk that does not start at column 0; the client
    copies such blocks in without ever holding the chunk's pair list."""
    import dataclasses

    from camplace.visibility import distributed as dist

    inst, pts, cands, _ = problem
    graded = dataclasses.replace(inst, quality=dataclasses.replace(inst.quality, mode="graded"))
    ref = compute_visibility(graded, cands, pts, chunk_size=16)
    task, _ = make_task(graded, cands, pts)
    block, counts = dist.run_chunk_bytes(task, 37, 81)
    assert block.dtype == np.uint8 and block.shape == (44, len(pts))
    np.testing.assert_array_equal(block, ref.qbytes.values[37:81])
    assert np.count_nonzero(block) > 0 and counts["observed"] == np.count_nonzero(block)
    values = np.zeros_like(ref.qbytes.values)
    got = dist._store_block(values, 37, 81, block, counts)
    np.testing.assert_array_equal(values[37:81], block)
    assert not values[:37].any() and not values[81:].any()
    assert got.col0 == 37 and len(got.rowids) == 0 and got.counts == counts
