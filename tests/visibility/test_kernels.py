"""The compiled culling / assembly kernels: invariances and direct checks.

The end-to-end agreement with the independent numpy oracle is in ``test_oracle*.py``; these
tests pin what the kernels add: the matrix does not depend on how the candidates are chunked or
threaded (nor on the chunk-local column width), the whole-frame frustum shortcut changes nothing,
every stored quality equals the documented formula, and Embree never writes the shared ``tfar``
array of ones.
"""

import dataclasses

import numpy as np
import pytest
import trimesh

from camplace.instance import builtin
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import chunk, compute_visibility, engine, make_target_points
from camplace.visibility.engine import assemble, compute_chunk, make_task
from camplace.visibility._embree import packet_api
from camplace.visibility.raycast import RayScene, _ones32


@pytest.fixture(scope="module")
def flyby():
    inst = builtin("comet-flyby")
    pts = make_target_points(inst, 3600, seed=11)
    cands = make_candidates("chaotic", 300, inst.volume.min_m, inst.volume.max_m, event_aims(inst, 3), seed=12)
    return inst, pts, cands


def same(a, b) -> bool:
    return (
        a.shape == b.shape
        and np.array_equal(a.indptr, b.indptr)
        and np.array_equal(a.indices, b.indices)
        and np.array_equal(a.data, b.data)
    )


def test_chunking_and_threads_do_not_change_the_matrix(flyby) -> None:
    inst, pts, cands = flyby
    ref = compute_visibility(inst, cands, pts, chunk_size=300, workers=1)  # one chunk, uint16 columns
    assert ref.matrix.nnz > 10_000
    for chunk, workers in ((1, 2), (7, 2), (64, 3), (256, 1)):
        vis = compute_visibility(inst, cands, pts, chunk_size=chunk, workers=workers)
        assert same(vis.matrix, ref.matrix), (chunk, workers)
        assert vis.stats == ref.stats
    m = ref.matrix
    assert m.has_sorted_indices and np.all(np.diff(m.indices[m.indptr[0]:m.indptr[1]]) > 0)
    for w in (1, 2, 5):  # assembly threads split the rows
        task, scenes = make_task(inst, cands, pts)
        parts = [compute_chunk(task, scenes, s, min(s + 50, len(cands))) for s in range(0, len(cands), 50)]
        assert same(assemble(task, parts, workers=w)[0], ref.matrix)


def test_whole_frame_shortcut_changes_nothing(flyby, monkeypatch) -> None:
    """Cameras holding a frame's whole point set skip the per-pair frustum test: forcing the
    per-pair test everywhere gives the same matrix and the same counts."""
    inst, pts, cands = flyby
    task, scenes = make_task(inst, cands, pts)
    whole = chunk.sphere_inside_view(*task.frame_spheres[0], task.cam_positions, task.cam_rotations, task.K,
                                      task.width_px, task.height_px, task.near_m, task.far_m)
    assert 0 < whole.sum() < len(whole)  # both paths are exercised
    ref = compute_visibility(inst, cands, pts, chunk_size=40)
    monkeypatch.setattr(chunk, "sphere_inside_view", lambda *a, **k: np.zeros(len(a[2]), dtype=bool))
    slow = compute_visibility(inst, cands, pts, chunk_size=40)
    assert same(slow.matrix, ref.matrix)
    assert slow.stats == ref.stats


def test_quality_is_the_documented_formula() -> None:
    """Every stored value equals min(1, fx / (d * required)) * cos(theta), computed here in numpy."""
    inst = builtin("comet-67p-bunker")
    inst = dataclasses.replace(inst, quality=dataclasses.replace(inst.quality, mode="graded", max_incidence_deg=80.0))
    pts = make_target_points(inst, 1500, seed=3)
    cands = make_candidates("uniform", 60, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=4)
    m = compute_visibility(inst, cands, pts, layout="csr").matrix.tocoo()  # the float32 values
    p, n = pts.positions[m.row], pts.normals[m.row]
    d = p - cands.positions[m.col]
    dist = np.linalg.norm(d, axis=1)
    cos_t = np.where(pts.is_emitter[m.row], 1.0, -np.einsum("ij,ij->i", d, n) / dist)
    fx = inst.camera.K()[0, 0]
    want = np.maximum(np.minimum(1.0, fx / (dist * inst.quality.required_px_per_m)) * cos_t, np.finfo(np.float32).tiny)
    assert len(m.data) > 1000 and np.all(m.data > 0) and np.all(cos_t >= np.cos(np.radians(80.0)) - 1e-12)
    assert np.ptp(m.data) > 0.1  # really graded
    np.testing.assert_allclose(m.data, want.astype(np.float32), rtol=2e-6, atol=0)


def test_live_rows_are_a_permutation_grouped_by_frame(flyby) -> None:
    inst, pts, cands = flyby
    task, _ = make_task(inst, cands, pts)
    live = task.live_rows
    assert np.array_equal(np.sort(live), np.nonzero(task.active)[0])
    assert np.all(np.diff(task.frame[live]) >= 0)
    start = task.live_arrays["frame_start"]
    assert start[0] == 0 and start[-1] == len(live)


def test_embree_leaves_the_shared_ones_untouched() -> None:
    ico = trimesh.creation.icosphere()
    scene = RayScene([(ico.vertices, ico.faces)])
    rng = np.random.default_rng(0)
    o = np.tile(np.float32([0.0, 0.0, -5.0]), (5000, 1))
    d = (rng.normal(size=(5000, 3)) * 0.2 + [0.0, 0.0, 10.0]).astype(np.float32)
    hit = scene.occluded_dir(o, d)
    assert 0.5 < hit.mean() <= 1.0
    assert np.all(_ones32(5000) == 1.0)
    out = np.ones(5000, dtype=bool)
    scene.occluded_dir(o, -d, out=out)  # pointing away: nothing blocks, written in place
    assert not out.any()


def test_block_culling_changes_nothing(monkeypatch) -> None:
    """Blocks of rows decided at once by the normal-cone bound give the per-row answer."""
    inst = builtin("comet-67p-bunker")
    assert inst.quality.max_incidence_deg >= 90.0  # no incidence limit: the block path applies
    pts = make_target_points(inst, 4000, seed=21)
    cands = make_candidates("chaotic", 120, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=22)
    task, _ = make_task(inst, cands, pts)
    lv = task.live_arrays
    # the bound really decides most blocks (checked here in numpy)
    d = task.cam_positions[:, None, :] - lv["block_centre"][None]
    s = np.einsum("cbk,bk->cb", d, lv["block_axis"])
    e = lv["block_spread"][None] * np.linalg.norm(d, axis=2)
    decided = (s + e - lv["block_h_lo"] < 0) | (s - e - lv["block_h_hi"] > task.support_tol[0])
    assert decided.mean() > 0.2  # (more with more points: blocks get smaller)
    ref = compute_visibility(inst, cands, pts, chunk_size=40)
    real = chunk._row_blocks

    def undecided(*args):
        out = real(*args)
        out["block_spread"] = np.full_like(out["block_spread"], np.inf)
        return out

    monkeypatch.setattr(chunk, "_row_blocks", undecided)
    plain = compute_visibility(inst, cands, pts, chunk_size=40)
    assert same(plain.matrix, ref.matrix)
    assert plain.stats == ref.stats


@pytest.mark.parametrize("n, size, workers", [(5000, 100, 2), (300, 256, 2), (5, 256, 8), (1000, 8, 3), (77, 10, 1)])
def test_chunk_plan_covers_every_candidate_once_in_order(n: int, size: int, workers: int) -> None:
    plan = engine.chunk_plan(n, size, workers)
    assert plan[0] == (0, min(size, n))  # the pilot keeps its size
    assert all(b0 == a1 for (_, b0), (a1, _) in zip(plan, plan[1:]))
    assert plan[-1][1] == n and all(0 < b - a <= min(size, 256) for a, b in plan)


def test_bits_set_straight_equal_the_pair_lists(flyby) -> None:
    """A chunk's bits set straight (``compute_chunk(..., words)``: camera by camera in one compiled
    call, :func:`_kernels.cast_chunk`) equal its pair list scattered (``compact`` then
    ``scatter_chunk``) and the CSR assembled from the same chunks, with the same counts, for
    chunks of every width (uint8 and uint16 local columns)."""
    from camplace.visibility.bits import bit_words
    from camplace.visibility.engine import scatter_part

    inst, pts, cands = flyby
    task, scenes = make_task(inst, cands, pts, quantised=False)
    n, m = len(cands), len(pts)
    for width in (1, 37, 300):
        straight = np.zeros((n, bit_words(m)), dtype=np.uint64)
        listed = np.zeros_like(straight)
        parts = []
        for s in range(0, n, width):
            e = min(s + width, n)
            a = compute_chunk(task, scenes, s, e, straight)
            b = compute_chunk(task, scenes, s, e)
            assert a.counts == b.counts
            assert len(a.lcols) == 0 and a.counts["observed"] == len(b.lcols)
            parts.append(b)
            scatter_part(listed, b)
        assert np.array_equal(straight, listed), width
        csr = assemble(task, parts)[0]
        dense = np.unpackbits(straight.view(np.uint8), axis=1, bitorder="little")[:, :m].T.astype(bool)
        assert int(dense.sum()) == csr.nnz > 10_000
        assert np.array_equal(dense, csr.toarray() != 0), width


def _bunker_inside_and_out():
    """comet-67p-bunker with candidates sampled in a box twice the room's size, so that some
    cameras stand inside the occluders' room (:attr:`VisibilityTask.enclosing_rest`) and some
    outside, chunk by chunk."""
    inst = builtin("comet-67p-bunker")
    lo, hi = np.asarray(inst.volume.min_m), np.asarray(inst.volume.max_m)
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    pts = make_target_points(inst, 3000, seed=5)
    cands = make_candidates("chaotic", 120, mid - 2 * half, mid + 2 * half, event_aims(inst, 3), seed=6)
    return inst, pts, cands


@pytest.mark.skipif(packet_api() is None, reason="no Embree 4 library beside embreex (chunks are cast whole)")
@pytest.mark.parametrize("graded", [False, True])
def test_camera_by_camera_cast_equals_the_chunk_pair_lists(graded: bool) -> None:
    """The chunk cast camera by camera in one compiled call (:func:`_kernels.cast_chunk`, into bits
    or quantised bytes) writes exactly the cells of the chunk's pair list (the steps over the whole
    chunk, then ``scatter_chunk`` / :func:`chunk.scatter_part_bytes`), with the same counts, on
    chunks where some cameras are inside the occluders' room and some outside: those inside skip
    their casts against the occluders camera by camera (fewer segments cast, never more) and
    the answer does not change. A planted wrong cell is seen."""
    from camplace.visibility.bits import bit_words
    from camplace.visibility.engine import scatter_part

    inst, pts, cands = _bunker_inside_and_out()
    if graded:
        inst = dataclasses.replace(inst, quality=dataclasses.replace(inst.quality, mode="graded"))
    task, scenes = make_task(inst, cands, pts, quantised=graded)
    n, m = len(cands), len(pts)
    inside = chunk._enclosed_cameras(task, task.cam_positions.astype(np.float32).astype(np.float64))[:, 0]
    assert 10 < inside.sum() < n - 10  # both kinds of camera
    assert chunk._packet_scenes(task, scenes) is not None  # the compiled path runs (Embree 4's packets)
    fewer = 0
    for width in (1, 37, 120):
        if width > 1:  # some chunk holds cameras inside and outside the room
            assert any(0 < inside[s:s + width].sum() < len(inside[s:s + width]) for s in range(0, n, width))
        if graded:
            straight = np.zeros((n, m), dtype=np.uint8)
            listed = np.zeros_like(straight)
        else:
            straight = np.zeros((n, bit_words(m)), dtype=np.uint64)
            listed = np.zeros_like(straight)
        observed = 0
        for s in range(0, n, width):
            e = min(s + width, n)
            a = compute_chunk(task, scenes, s, e, values=straight) if graded else compute_chunk(task, scenes, s, e, straight)
            observed += a.counts["observed"]
            b = compute_chunk(task, scenes, s, e)
            assert len(a.lcols) == 0 and a.counts["observed"] == len(b.lcols)
            assert {k: v for k, v in a.counts.items() if k != "cast"} == {k: v for k, v in b.counts.items() if k != "cast"}
            assert a.counts["cast"] <= b.counts["cast"]
            fewer += b.counts["cast"] - a.counts["cast"]
            if graded:
                chunk.scatter_part_bytes(task, listed, b)
            else:
                scatter_part(listed, b)
        cells = np.count_nonzero(straight) if graded else int(np.unpackbits(straight.view(np.uint8)).sum())
        assert cells == observed > 10_000
        assert np.array_equal(straight, listed), width
        planted = straight.copy()
        planted.flat[np.flatnonzero(planted)[len(np.flatnonzero(planted)) // 2]] ^= 1
        assert not np.array_equal(planted, listed)
    assert fewer > 0  # mixed chunks: the pair lists cast the inside cameras' segments, camera by camera does not
