"""Mesh files of an instance: read any triangle mesh trimesh understands, with consistent winding.

(Writing goes through :func:`camplace.geometry.ply_bytes`.)
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["read_mesh_file", "make_winding_consistent"]


def _is_closed(faces: np.ndarray) -> bool:
    """True when every edge is shared by exactly two triangles (a watertight surface)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def read_mesh_file(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read any triangle mesh trimesh understands, unprocessed (vertex order and count kept).

    Faces whose winding is inconsistent are re-oriented consistently (:func:`make_winding_consistent`);
    the overall orientation is kept as the file has it (a room scanned from inside stays inward).

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    """
    import trimesh

    mesh = trimesh.load(str(path), force="mesh", process=False)
    if len(mesh.vertices) == 0:  # a point cloud (no faces) loads as an empty mesh: say "no triangles"
        raw = trimesh.load(str(path), process=False)
        points = np.asarray(getattr(raw, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
        return points, np.zeros((0, 3), dtype=np.int64)
    vertices = np.ascontiguousarray(np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3))
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    faces = np.ascontiguousarray(faces.reshape(-1, 3) if faces.size else np.zeros((0, 3), dtype=np.int64))
    if len(vertices) and len(faces) and np.all(np.isfinite(vertices)) and faces.min() >= 0 and faces.max() < len(vertices):
        faces = make_winding_consistent(faces)
    return vertices, faces


def make_winding_consistent(faces: np.ndarray) -> np.ndarray:
    """Flip faces so that every manifold edge is traversed in opposite directions by its two faces.

    In each connected patch (faces joined by edges shared by exactly two faces) the face with the
    lowest index keeps its orientation. Consistent input is returned unchanged (same array values).

    Parameters
    ----------
    faces : (m, 3) int64

    Returns
    -------
    (m, 3) int64
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    faces = np.asarray(faces, dtype=np.int64)
    m = len(faces)
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    undirected = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    inverse = np.asarray(inverse).reshape(-1)
    manifold = np.flatnonzero(counts[inverse] == 2)
    order = manifold[np.argsort(inverse[manifold], kind="stable")]
    first, second = order[0::2], order[1::2]
    fa, fb = first // 3, second // 3
    same_direction = directed[first, 0] == directed[second, 0]  # both faces walk the edge the same way
    if not same_direction.any():
        return faces
    keep = fa != fb
    fa, fb, same_direction = fa[keep], fb[keep], same_direction[keep]
    # edge weight 1: neighbours agree, 2: one of them must be flipped relative to the other
    src, dst = np.concatenate([fa, fb]), np.concatenate([fb, fa])
    weight = np.concatenate([same_direction, same_direction]).astype(np.int8) + 1
    graph = coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(m, m)).tocsr()
    key = src * m + dst
    by_key = np.argsort(key, kind="stable")
    sorted_key, sorted_weight = key[by_key], weight[by_key]
    flip = np.zeros(m, dtype=bool)
    _, labels = connected_components(graph, directed=False)
    for root in np.unique(labels, return_index=True)[1]:
        bfs, pred = breadth_first_order(graph, int(root), directed=False, return_predecessors=True)
        nodes = bfs[1:].astype(np.int64)
        parents = pred[nodes].astype(np.int64)  # csgraph gives int32: widen before parents * m
        opposite = (sorted_weight[np.searchsorted(sorted_key, parents * m + nodes)] == 2).tolist()
        # parity propagates root -> leaves in BFS order (parents come first)
        for node, parent, opp in zip(nodes.tolist(), parents.tolist(), opposite):
            flip[node] = flip[parent] ^ opp
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out
