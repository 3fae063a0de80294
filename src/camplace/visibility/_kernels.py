"""Compiled (numba, GIL-free) kernels of the visibility engine (:mod:`camplace.visibility.engine`).

The tests of one (row, candidate) pair are those of :mod:`camplace.visibility.engine`: depth
range, image bounds, facing, incidence and the supporting-plane shortcut. The kernels run in
three steps per chunk of candidates:

1. :func:`cull` walks every (camera, live row) pair and keeps the indices of the pairs that
   survive, camera-major with rows in live-row order, with the scene each is cast against
   (frame x {full scene, occluders alone}), counting each culling step;
2. :func:`build_segments` writes the float32 segments of the kept pairs grouped by scene, so
   each group is one contiguous slice for Embree;
3. :func:`compact` keeps the pairs whose segment was not blocked, as a row list (the chunk's
   own small CSR, built in cache, one byte a pair), or :func:`set_bits` sets their bits in the
   column bitsets;

:func:`cast_chunk` runs the three steps, the Embree casts (:mod:`camplace.visibility._castkernels`)
and :func:`set_bits` (or, for quantised columns, :func:`set_quality`) camera by camera in one call:
its work arrays hold one camera's pairs (about 34 bytes a live row) instead of a chunk's, and the
chunk takes the interpreter's lock once;

and :func:`merge_rows` copies the chunks' row runs into the matrix's CSR arrays, computing each
pair's observation quality on the way; :func:`supporting` finds the rows whose tangent plane
supports the target.

All of them release the GIL (``nogil=True``), so the chunk threads run them on every core.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from camplace.visibility._castkernels import occluded_packets
from camplace.visibility.qbytes import quantise

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}




@numba.njit(**_JIT)
def cull(
    cam_pos, cam_rot, whole, frame_start, live_pos, live_nrm, live_ndotp, live_emit, live_support, support_tol,
    frame_blocks, block_start, block_centre, block_axis, block_spread, block_h_lo, block_h_hi, block_emit,
    block_reach, fx, fy, cx, cy, width_px, height_px, near_m, far_m, cos_max, kept, group, sizes,
):  # pragma: no cover - compiled
    """Pairs passing range, frustum, facing and incidence.

    Parameters
    ----------
    cam_pos : (c, 3) float64
    cam_rot : (c, 3, 3) float64
        World-to-camera: ``x_cam = (x - c) @ R``.
    whole : (c, n_frames) bool
        The camera holds the frame's whole live point set inside its frustum and range (its
        rows skip the per-pair frustum test).
    frame_start : (n_frames + 1,) int64
        Live rows come frame by frame: frame f's are ``frame_start[f]:frame_start[f + 1]``.
    live_pos, live_nrm : (l, 3) float64
    live_ndotp : (l,) float64
        ``n . p`` of every live row.
    live_emit : (l,) bool
    live_support : (l,) bool
        The row's tangent plane supports the target (see ``VisibilityTask.support``).
    support_tol : (n_frames,) float64
    frame_blocks, block_start, block_centre, block_axis, block_spread, block_h_lo, block_h_hi, block_emit, block_reach
        Blocks of consecutive live rows (see ``VisibilityTask.live_arrays``): for a camera that
        holds the frame in view (and no incidence limit), a block whose facing test has the same
        answer for every row, by the bound ``n . (c - p) in [s - e - h_hi, s + e - h_lo]`` with
        ``d = c - centre``, ``s = axis . d``, ``e = spread |d|``, is decided at once.
    fx, fy, cx, cy : float
    width_px, height_px : int
    near_m, far_m, cos_max : float
    kept : (>= c * l,) int32
        Scratch output: ``kept[:q]`` receives the live-row index of each kept pair,
        camera-major, in live-row order.
    group : (>= c * l,) int8
        Scratch output: ``group[:q]`` the scene group of each kept pair: ``2 * f`` for frame f's
        full scene, ``2 * f + 1`` for its occluders alone (supporting-plane rows seen from
        their outer side, ``n . (c - p) > support_tol[f]``).
    sizes : (2 * n_frames,) int64
        Output: kept pairs in each group (must come in zeroed).

    Returns
    -------
    q : int
        Kept pairs.
    per_cam : (c,) int64
        Kept pairs of each camera.
    counts : (3,) int64
        Pairs in range, in the frustum, and facing (incidence included).
    """
    nc = cam_pos.shape[0]
    n_frames = frame_start.shape[0] - 1
    per_cam = np.zeros(nc, dtype=np.int64)
    counts = np.zeros(3, dtype=np.int64)
    u_lo, u_hi = -0.5, width_px - 0.5
    v_lo, v_hi = -0.5, height_px - 0.5
    incidence = cos_max > 0.0
    q = 0
    for c in range(nc):
        px, py, pz = cam_pos[c, 0], cam_pos[c, 1], cam_pos[c, 2]
        r = cam_rot[c]
        start = q
        slack = 1e-10 * (math.sqrt(px * px + py * py + pz * pz) + block_reach)  # >> rounding of a dot
        for f in range(n_frames):
            tol_f = support_tol[f]
            q_f = q
            n_rest = 0
            inside = whole[c, f]  # the whole frame is in view: skip the per-pair frustum test
            if inside:
                counts[0] += frame_start[f + 1] - frame_start[f]
                counts[1] += frame_start[f + 1] - frame_start[f]
            for bk in range(frame_blocks[f], frame_blocks[f + 1]):
                lo, hi = block_start[bk], block_start[bk + 1]
                if inside and not incidence and not block_emit[bk]:
                    # n_i . (c - p_i) lies within [s - e - h_hi, s + e - h_lo] for every row of the block
                    dx = px - block_centre[bk, 0]
                    dy = py - block_centre[bk, 1]
                    dz = pz - block_centre[bk, 2]
                    s_ = dx * block_axis[bk, 0] + dy * block_axis[bk, 1] + dz * block_axis[bk, 2]
                    e_ = block_spread[bk] * math.sqrt(dx * dx + dy * dy + dz * dz)
                    if s_ + e_ - block_h_lo[bk] < -slack:  # no row faces the camera
                        continue
                    if s_ - e_ - block_h_hi[bk] > tol_f + slack:  # every row faces it, beyond tol
                        for i in range(lo, hi):
                            rest = np.int64(live_support[i])
                            kept[q] = i
                            group[q] = 2 * f + rest
                            q += 1
                            n_rest += rest
                        continue
                for i in range(lo, hi):
                    if not inside:
                        dx = live_pos[i, 0] - px
                        dy = live_pos[i, 1] - py
                        dz = live_pos[i, 2] - pz
                        z = dx * r[0, 2] + dy * r[1, 2] + dz * r[2, 2]
                        if z < near_m or z > far_m:
                            continue
                        counts[0] += 1
                        x = dx * r[0, 0] + dy * r[1, 0] + dz * r[2, 0]
                        u = fx * x / z + cx
                        if u < u_lo or u >= u_hi:
                            continue
                        y = dx * r[0, 1] + dy * r[1, 1] + dz * r[2, 1]
                        v = fy * y / z + cy
                        if v < v_lo or v >= v_hi:
                            continue
                        counts[1] += 1
                    # facing, incidence and scene group without branches (emitters pass both
                    # tests): the index is written unconditionally, the cursor advances if kept
                    nx, ny, nz = live_nrm[i, 0], live_nrm[i, 1], live_nrm[i, 2]
                    emit = live_emit[i]
                    dot = px * nx + py * ny + pz * nz - live_ndotp[i]  # n . (c - p)
                    ok = emit | (dot > 0.0)
                    if incidence:
                        dx = live_pos[i, 0] - px
                        dy = live_pos[i, 1] - py
                        dz = live_pos[i, 2] - pz
                        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
                        cos_t = -(dx * nx + dy * ny + dz * nz) / max(dist, 1e-300)
                        ok = ok & (emit | (cos_t >= cos_max))
                    rest = np.int64(live_support[i]) * np.int64(dot > tol_f)
                    k = np.int64(ok)
                    kept[q] = i
                    group[q] = 2 * f + rest
                    q += k
                    n_rest += k * rest
            sizes[2 * f] += q - q_f - n_rest
            sizes[2 * f + 1] += n_rest
        per_cam[c] = q - start
    counts[2] = q
    return q, per_cam, counts


@numba.njit(**_JIT)
def build_segments(kept, group, sizes, per_cam, cam_pos32, live_ends32, origins, directions, slot):  # pragma: no cover
    """Float32 segments of the kept pairs, grouped by scene.

    Parameters
    ----------
    kept, group : (q,) int32, int8
    sizes : (g,) int64
        From :func:`cull`.
    cam_pos32 : (c, 3) float32
    live_ends32 : (l, 3) float32
        Segment end of every live row.
    origins, directions : (>= q, 3) float32
        Output: segments camera -> ``p + eps n``, grouped (group g is ``offsets[g]:offsets[g + 1]``).
    slot : (>= q,) int32
        Output: position of each kept pair (camera-major order) in the grouped arrays.

    Returns
    -------
    offsets : (g + 1,) int64
    """
    n_groups = sizes.shape[0]
    offsets = np.zeros(n_groups + 1, dtype=np.int64)
    for g in range(n_groups):
        offsets[g + 1] = offsets[g] + sizes[g]
    fill = offsets[:-1].copy()
    j = 0
    for c in range(per_cam.shape[0]):
        ox, oy, oz = cam_pos32[c, 0], cam_pos32[c, 1], cam_pos32[c, 2]
        for _ in range(per_cam[c]):
            i = kept[j]
            g = group[j]
            s = fill[g]
            fill[g] = s + 1
            slot[j] = s
            origins[s, 0] = ox
            origins[s, 1] = oy
            origins[s, 2] = oz
            directions[s, 0] = live_ends32[i, 0] - ox
            directions[s, 1] = live_ends32[i, 1] - oy
            directions[s, 2] = live_ends32[i, 2] - oz
            j += 1
    return offsets


@numba.njit(**_JIT)
def compact(kept, per_cam, slot, blocked, live_rows, row_cursor, rowids, offsets, lcols):  # pragma: no cover
    """The unblocked pairs of a chunk as a compressed row list (a CSR of the chunk's nonempty rows).

    Parameters
    ----------
    kept, per_cam, slot, blocked
        From :func:`cull`, :func:`build_segments` and the casts.
    live_rows : (l,) int64
        Global row of each live row.
    row_cursor : (l,) int64
        Scratch.
    rowids : (>= l,) int32
        Output: ``rowids[:r]`` are the global rows with an observed pair, in live-row order.
    offsets : (>= l + 1,) int64
        Output: row t's pairs are ``offsets[t]:offsets[t + 1]`` of ``lcols``.
    lcols : (o,) uint8 or uint16
        Output, o = number of unblocked pairs: the chunk-local camera of each pair, ascending
        within each row. (The quality is recomputed from the row and the camera when the
        matrix is assembled: 1 byte a pair is all that waits in memory.)

    Returns
    -------
    r : int
        Rows with an observed pair.
    """
    nl = live_rows.shape[0]
    for i in range(nl):
        row_cursor[i] = 0
    j = 0
    for c in range(per_cam.shape[0]):
        for _ in range(per_cam[c]):
            row_cursor[kept[j]] += 1 - blocked[slot[j]]
            j += 1
    r = 0
    total = 0
    for i in range(nl):
        cnt = row_cursor[i]
        if cnt > 0:
            rowids[r] = live_rows[i]
            offsets[r] = total
            row_cursor[i] = total
            total += cnt
            r += 1
    offsets[r] = total
    j = 0
    for c in range(per_cam.shape[0]):
        for _ in range(per_cam[c]):
            if not blocked[slot[j]]:
                i = kept[j]
                at = row_cursor[i]
                lcols[at] = c
                row_cursor[i] = at + 1
            j += 1
    return r


@numba.njit(**_JIT)
def set_bits(kept, per_cam, slot, blocked, live_rows, col0, words):  # pragma: no cover - compiled
    """Set the bits of a chunk's unblocked pairs straight in the column bitsets (what
    :func:`compact` then :func:`camplace.visibility.bits.scatter_chunk` do, in one pass and with
    no pair list: camera-major, so each camera's column is written in one run).

    Parameters
    ----------
    kept, per_cam, slot, blocked, live_rows
        As :func:`compact` takes them.
    col0 : int
        Global column of the chunk's first camera.
    words : (n, W) uint64
        Written in place: only the chunk's columns.

    Returns
    -------
    int
        Unblocked pairs (bits set).
    """
    j = 0
    n = 0
    for c in range(per_cam.shape[0]):
        col = col0 + c
        for _ in range(per_cam[c]):
            if not blocked[slot[j]]:
                r = live_rows[kept[j]]
                words[col, r >> 6] |= np.uint64(1) << np.uint64(r & 63)
                n += 1
            j += 1
    return n


@numba.njit(**_JIT)
def set_quality(kept, per_cam, slot, blocked, live_rows, col, values, positions, normals, emitter, cam_pos, fx,
                required_px_per_m):  # pragma: no cover - compiled
    """Write the quantised quality (:func:`pair_quality`, then
    :func:`camplace.visibility.qbytes.quantise`) of one camera's unblocked pairs into its column
    ``values[col]`` ((n, m) uint8), as :func:`scatter_chunk_quality` does from a row list.

    Parameters
    ----------
    kept, per_cam, slot, blocked, live_rows
        As :func:`set_bits` takes them, for the one camera (``per_cam`` (1,)).
    col : int
        Global column of the camera (also its row of ``cam_pos``).
    values : (n, m) uint8
    positions, normals : (m, 3) float64
    emitter : (m,) bool
    cam_pos : (n, 3) float64
    fx, required_px_per_m : float

    Returns
    -------
    int
        Unblocked pairs (cells written).
    """
    n = 0
    for j in range(per_cam[0]):
        if not blocked[slot[j]]:
            r = live_rows[kept[j]]
            values[col, r] = quantise(np.float64(pair_quality(r, col, positions, normals, emitter, cam_pos, fx,
                                                              required_px_per_m)))
            n += 1
    return n


@numba.njit(**_JIT)
def cast_chunk(
    cam_pos, cam_rot, whole, enclosed, frame_start, live_pos, live_nrm, live_ndotp, live_emit, live_support, support_tol,
    frame_blocks, block_start, block_centre, block_axis, block_spread, block_h_lo, block_h_hi, block_emit,
    block_reach, fx, fy, cx, cy, width_px, height_px, near_m, far_m, cos_max, live_ends32, fn, width, scenes,
    live_rows, col0, words, values, positions, normals, emitter, all_cam_pos, required_px_per_m,
    kept, group, origins, directions, slot, blocked,
):  # pragma: no cover - compiled
    """A chunk of candidates cast and written into the matrix, one camera at a time: :func:`cull`,
    :func:`build_segments`, the Embree casts
    (:func:`camplace.visibility._castkernels.occluded_packets`), then :func:`set_bits` into the
    column bitsets ``words`` or, when ``words`` has no rows, :func:`set_quality` into the quantised
    columns ``values``: the same answer as those steps over the whole chunk (each pair's tests and
    segment do not depend on the other cameras).

    Parameters
    ----------
    cam_pos, cam_rot, whole, frame_start, ..., cos_max
        As :func:`cull` takes them (``whole``: (c, n_frames) bool).
    enclosed : (c, n_frames) bool
        The camera is inside frame f's occluder room (``VisibilityTask.enclosing_rest``): its
        segments of group ``2 f + 1`` meet nothing and are not cast.
    live_ends32 : (l, 3) float32
        As :func:`build_segments` takes it.
    fn : uint64
        Address of ``rtcOccluded{width}``.
    width : int
        Rays per Embree call.
    scenes : (2 * n_frames,) uint64
        The committed Embree scene of each group (frame f's full scene ``2 f``, its occluders
        alone ``2 f + 1``); 0 for a scene with no triangles (nothing blocks).
    live_rows : (l,) int64
        Global row of each live row.
    col0 : int
        Global column of the chunk's first camera.
    words : (n, W) uint64
        Column bitsets, written in place (only the chunk's columns); (0, 1) for quantised columns.
    values : (n, m) uint8
        Quantised columns, written in place (only the chunk's columns) when ``words`` has no rows.
    positions, normals : (m, 3) float64
    emitter : (m,) bool
    all_cam_pos : (n, 3) float64
        Every candidate's position (the quality of a pair, :func:`pair_quality`).
    required_px_per_m : float
        The quality's scale (``fx`` of the chunk's camera model grades it).
    kept, group, origins, directions, slot, blocked : work arrays of at least l entries
        int32, int8, (l, 3) float32, (l, 3) float32, int32, bool.

    Returns
    -------
    (5,) int64
        Pairs in range, in the frustum, facing (as :func:`cull` counts them), segments cast,
        and unblocked pairs (bits set or cells written).
    """
    nc = cam_pos.shape[0]
    n_groups = scenes.shape[0]
    out = np.zeros(5, dtype=np.int64)
    sizes = np.zeros(n_groups, dtype=np.int64)
    pos32 = cam_pos.astype(np.float32)
    for c in range(nc):
        sizes[:] = 0
        q, per_cam, steps = cull(
            cam_pos[c:c + 1], cam_rot[c:c + 1], whole[c:c + 1], frame_start, live_pos, live_nrm, live_ndotp,
            live_emit, live_support, support_tol, frame_blocks, block_start, block_centre, block_axis, block_spread,
            block_h_lo, block_h_hi, block_emit, block_reach, fx, fy, cx, cy, width_px, height_px, near_m, far_m,
            cos_max, kept, group, sizes,
        )
        out[0] += steps[0]
        out[1] += steps[1]
        out[2] += steps[2]
        if q == 0:
            continue
        offsets = build_segments(kept, group, sizes, per_cam, pos32[c:c + 1], live_ends32, origins, directions, slot)
        for g in range(n_groups):
            lo, hi = offsets[g], offsets[g + 1]
            if hi == lo:
                continue
            if g % 2 == 1 and enclosed[c, g // 2]:
                blocked[lo:hi] = False
                continue
            out[3] += hi - lo
            if scenes[g] == 0:  # (counted as cast, as RayScene.occluded_dir of no triangles is)
                blocked[lo:hi] = False
                continue
            occluded_packets(fn, scenes[g], width, origins[lo:hi], directions[lo:hi], blocked[lo:hi])
        if words.shape[0] > 0:
            out[4] += set_bits(kept, per_cam, slot, blocked, live_rows, col0 + c, words)
        else:
            out[4] += set_quality(kept, per_cam, slot, blocked, live_rows, col0 + c, values, positions, normals,
                                  emitter, all_cam_pos, fx, required_px_per_m)
    return out


@numba.njit(**_JIT)
def pair_quality(r, col, positions, normals, emitter, cam_pos, fx, required_px_per_m):  # pragma: no cover - compiled
    """The graded observation quality of row ``r`` seen from camera ``col``, float32:
    ``min(1, fx / (d * required_px_per_m)) * cos(theta)`` (``cos(theta) = 1`` for emitters), floored
    at the smallest normal float32."""
    tiny = np.float32(1.1754944e-38)
    dx = positions[r, 0] - cam_pos[col, 0]
    dy = positions[r, 1] - cam_pos[col, 1]
    dz = positions[r, 2] - cam_pos[col, 2]
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    if emitter[r]:
        cos_t = 1.0
    else:
        cos_t = -(dx * normals[r, 0] + dy * normals[r, 1] + dz * normals[r, 2]) / max(dist, 1e-300)
    v32 = np.float32(min(1.0, fx / (dist * required_px_per_m)) * cos_t)
    return v32 if v32 > tiny else tiny


@numba.njit(**_JIT)
def merge_rows(
    rowids, offsets, lcols, col0, row_lo, row_hi, nxt, indices, data,
    graded, positions, normals, emitter, cam_pos, fx, required_px_per_m,
):  # pragma: no cover - compiled
    """Append the runs of a chunk's row list (see :func:`compact`) that belong to rows
    ``row_lo:row_hi`` to a CSR under construction, with their observation quality.

    ``nxt[r]`` is the next free slot of row r in ``indices`` / ``data``. The quality is 1, or
    with ``graded`` :func:`pair_quality`.
    """
    one = np.float32(1.0)
    for t in range(rowids.shape[0]):
        r = rowids[t]
        if r < row_lo or r >= row_hi:
            continue
        at = nxt[r]
        for x in range(offsets[t], offsets[t + 1]):
            col = col0 + lcols[x]
            indices[at] = col
            if graded:
                data[at] = pair_quality(r, col, positions, normals, emitter, cam_pos, fx, required_px_per_m)
            else:
                data[at] = one
            at += 1
        nxt[r] = at


@numba.njit(**_JIT)
def scatter_chunk_quality(rowids, offsets, lcols, col0, values, positions, normals, emitter, cam_pos, fx,
                          required_px_per_m):  # pragma: no cover - compiled
    """Write the quantised qualities of a chunk's observed pairs
    (:class:`camplace.visibility.chunk.ChunkResult`) into ``values`` ((n, m) uint8, only the chunk's
    columns): :func:`pair_quality` (float32), then :func:`camplace.visibility.qbytes.quantise`."""
    for t in range(rowids.shape[0]):
        r = rowids[t]
        for p in range(offsets[t], offsets[t + 1]):
            c = col0 + np.int64(lcols[p])
            v = pair_quality(r, c, positions, normals, emitter, cam_pos, fx, required_px_per_m)
            values[c, r] = quantise(np.float64(v))


@numba.njit(**_JIT)
def supporting_hull(lo, hi, verts, indptr, neighbours, seeds, positions, normals, tol, out):  # pragma: no cover - compiled
    """``out[i] = max_v n_i . (v - p_i) <= tol`` over a convex hull's vertices, rows ``lo:hi``,
    by ascent along the hull's edges.

    A linear function on a convex polytope has no local maximum at a vertex that is not a global
    one, so from the best of ``seeds`` the ascent moves to the best neighbour while one is strictly
    higher and stops at the maximum (or as soon as a vertex is above the plane): about a hundred
    products a row where the plain test makes one per hull vertex (40,000 on a fine sphere). With
    every vertex a seed and no edges it is the plain test (a target with no 3D hull).

    Parameters
    ----------
    lo, hi : int
        The block of rows.
    verts : (h, 3) float64
        The hull's vertices.
    indptr : (h + 1,) int64
    neighbours : (e,) int64
        Vertex ``v``'s neighbours along the hull's edges: ``neighbours[indptr[v]:indptr[v + 1]]``.
    seeds : (s,) int64
        Starting vertices (spread over the hull).
    positions, normals : (r, 3) float64
    tol : float
    out : (r,) bool
    """
    for i in range(lo, hi):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        lim = nx * positions[i, 0] + ny * positions[i, 1] + nz * positions[i, 2] + tol
        v = seeds[0]
        best = nx * verts[v, 0] + ny * verts[v, 1] + nz * verts[v, 2]
        for s in range(1, seeds.shape[0]):
            q = seeds[s]
            val = nx * verts[q, 0] + ny * verts[q, 1] + nz * verts[q, 2]
            if val > best:
                best = val
                v = q
        while best <= lim:
            nxt = v
            for e in range(indptr[v], indptr[v + 1]):
                q = neighbours[e]
                val = nx * verts[q, 0] + ny * verts[q, 1] + nz * verts[q, 2]
                if val > best:
                    best = val
                    nxt = q
            if nxt == v:
                break
            v = nxt
        out[i] = best <= lim
