"""Visibility chunks on a Dask distributed cluster (optional extra: ``pip install 'camplace[dask]'``).

The task (plain arrays) is scattered once to every worker; each worker process builds its Embree
scenes once per task and computes candidate chunks. Chunk results are put back in column order,
so the matrix is identical to the in-process one. Dask re-runs the chunks of a worker that dies.
"""

from __future__ import annotations

import logging
import weakref
from typing import Any, Callable

from camplace.errors import CamplaceError
from camplace.visibility.chunk import compute_chunk

log = logging.getLogger(__name__)

# Worker-side: Embree scenes built for each scattered task object, built once per process.
_SCENES: "weakref.WeakKeyDictionary[Any, dict]" = weakref.WeakKeyDictionary()

INSTALL_HINT = "--dask needs the optional Dask extra (install it with: pip install 'camplace[dask]')"


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise CamplaceError(INSTALL_HINT) from None
    return distributed


def run_chunk(task, start: int, stop: int):
    """Worker entry point: compute candidates ``start:stop`` of ``task``."""
    scenes = _SCENES.get(task)
    if scenes is None:
        scenes = task.build_scenes()
        _SCENES[task] = scenes
    return compute_chunk(task, scenes, start, stop)


def run_chunk_bits(task, start: int, stop: int):
    """Worker entry point for a binary matrix: candidates ``start:stop`` of ``task`` as column
    bitsets ((stop - start, ceil(m / 64)) uint64, see :mod:`camplace.visibility.bits`) and the
    chunk's counts. One bit a cell goes back to the client, never a pair list or floats."""
    import numpy as np

    from camplace.visibility.bits import bit_words, scatter_chunk

    part = run_chunk(task, start, stop)
    block = np.zeros((stop - start, bit_words(len(task.positions))), dtype=np.uint64)
    if len(part.rowids):
        scatter_chunk(part.rowids, part.offsets, part.lcols, 0, block)
    return block, part.counts


def run_chunk_bytes(task, start: int, stop: int):
    """Worker entry point for a graded matrix quantised to bytes: candidates ``start:stop`` of
    ``task`` as quantised columns ((stop - start, m) uint8, see :mod:`camplace.visibility.qbytes`)
    and the chunk's counts. One byte a cell goes back to the client, never a pair list or floats."""
    import numpy as np

    from camplace.visibility.chunk import scatter_part_bytes

    part = run_chunk(task, start, stop)
    block = np.zeros((stop - start, len(task.positions)), dtype=np.uint8)
    return block, scatter_part_bytes(task, block, part, origin=start).counts


def connect(address: str):
    """A Dask client for ``address``: a scheduler address (``tcp://host:8786``) or ``local:N``.

    Returns
    -------
    client : distributed.Client
    cluster : distributed.LocalCluster or None
        The local cluster started for ``local:N`` (close it after the client).
    """
    distributed = _import_distributed()
    if address.startswith("local:"):
        try:
            n = int(address.split(":", 1)[1])
            if n < 1:
                raise ValueError
        except ValueError:
            raise CamplaceError(f"--dask: {address!r}: write local:N with N >= 1 worker processes") from None
        cluster = distributed.LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR
        )
        return distributed.Client(cluster), cluster
    try:
        return distributed.Client(address, timeout="20s"), None
    except (OSError, TimeoutError) as exc:
        raise CamplaceError(f"--dask: cannot reach a Dask scheduler at {address!r} ({exc}; check the address)") from None


def compute_chunks_dask(
    task,
    starts: list[int],
    chunk_size: int,
    address: str | None = None,
    *,
    client=None,
    progress: Callable[[int], None] | None = None,
    stops: list[int] | None = None,
    words=None,
    values=None,
) -> list:
    """Compute the chunks starting at ``starts`` on a Dask cluster; results in the order of ``starts``.

    Parameters
    ----------
    task : VisibilityTask
    starts : list of int
    chunk_size : int
    address : str or None
        Scheduler address or ``local:N`` (ignored when ``client`` is given).
    client : distributed.Client or None
        An existing client to use.
    progress : callable or None
        Called with the number of candidates finished as chunks complete.
    stops : list of int or None
        The end of each chunk (default ``start + chunk_size``, at most the candidate count): a
        team's chunks end at its model boundaries.
    words : (n, ceil(m / 64)) uint64 array or None
        A binary matrix's column bitsets: the workers hand back bit-packed column blocks, copied
        into ``words`` as they arrive (and released on the cluster); the results are then the
        chunks' counts with empty pair arrays.
    values : (n, m) uint8 array or None
        A graded matrix's quantised columns: the workers hand back byte column blocks, copied into
        ``values`` as they arrive (the same results as with ``words``).
    """
    if words is not None and values is not None:
        raise ValueError("compute_chunks_dask: words or values, not both")
    if not starts:
        return []
    distributed = _import_distributed()
    own = client is None
    cluster = None
    if own:
        client, cluster = connect(address or "local:2")
    try:
        n = task.n_candidates
        remote_task = client.scatter(task, broadcast=True, hash=False)
        futures = {}
        end = {s: (stops[i] if stops is not None else min(s + chunk_size, n)) for i, s in enumerate(starts)}
        entry = run_chunk_bits if words is not None else run_chunk_bytes if values is not None else run_chunk
        for s in starts:
            fut = client.submit(entry, remote_task, s, end[s], pure=False, retries=5)
            futures[fut] = s
        results = {}
        for fut in distributed.as_completed(list(futures)):
            s = futures.pop(fut)
            got = fut.result()
            fut.release()
            if words is not None or values is not None:
                got = _store_block(words if words is not None else values, s, end[s], *got)
            results[s] = got
            if progress is not None:
                progress(end[s] - s)
        return [results[s] for s in starts]
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()


def _store_block(columns, start: int, stop: int, block, counts: dict):
    """Copy a worker's column block into rows ``start:stop`` of ``columns`` (bitsets or bytes;
    a scratch file's pages are then dropped from memory) and return the chunk's counts as a
    :class:`~camplace.visibility.chunk.ChunkResult` with empty pair arrays."""
    import numpy as np

    from camplace.visibility.chunk import ChunkResult
    from camplace.visibility.scratch import release_pages

    columns[start:stop] = block
    row = columns.shape[1] * columns.itemsize
    release_pages(columns, start * row, stop * row)  # out of core: to disk
    return ChunkResult(start, np.empty(0, np.int32), np.zeros(1, np.int64), np.empty(0, np.uint8), counts)
