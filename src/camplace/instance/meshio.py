"""Mesh files of an instance: read any triangle mesh trimesh understands, with consistent winding.

Files often split vertices that share a position (texture seams: one position, two texture
coordinates). The topology checks (:func:`is_watertight`, the winding) therefore work on the faces
welded by position (:func:`welded_faces`); the vertices themselves are kept as the file has them.

(Writing goes through :func:`camplace.geometry.ply_bytes`.)
"""

from __future__ import annotations

import os
import re

import numpy as np

from camplace.errors import CamplaceError

__all__ = ["read_mesh_file", "make_winding_consistent", "welded_faces", "is_watertight", "MissingPackageError"]

#: pip names of the modules trimesh imports lazily while reading a file, where they differ
PIP_NAMES = {"PIL": "pillow", "yaml": "pyyaml", "skimage": "scikit-image"}


class MissingPackageError(CamplaceError):
    """trimesh needs a Python package that is not installed to read a mesh file.

    Attributes
    ----------
    package : str or None
        The pip name of the missing package (``pillow`` for ``PIL``); None when the error does not
        name a module.
    reason : str
        What is missing, without the fix.
    fix : str
        How to install it.
    """

    def __init__(self, path: str | os.PathLike[str], exc: ImportError) -> None:
        module = missing_module(exc)
        self.package = None if module is None else PIP_NAMES.get(module, module)
        what = f"the Python package '{self.package}'" if self.package else "a Python package"
        self.reason = f"reading {os.path.basename(path)} needs {what}, which is not installed ({type(exc).__name__}: {exc})"
        self.fix = f"install it: pip install {self.package}" if self.package else "install the package the message names"
        super().__init__(f"{self.reason} ({self.fix})")


def missing_module(exc: ImportError) -> str | None:
    """The top-level module an ImportError is about, or None.

    ``exc.name`` when set; else read from the message (trimesh re-raises a deferred import error
    without its ``name``: ``import of PIL halted; None in sys.modules``).
    """
    name = exc.name
    if not name:
        m = re.search(r"No module named '([\w.]+)'|import of ([\w.]+) halted|cannot import name '\w+' from '([\w.]+)'", str(exc))
        name = next((g for g in m.groups() if g), None) if m else None
    return name.partition(".")[0] if name else None


def _is_closed(faces: np.ndarray) -> bool:
    """True when every edge is shared by exactly two triangles (a watertight surface)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def welded_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The faces re-indexed onto the vertices merged by position (as trimesh's ``merge_vertices``).

    Vertices split only by their texture coordinates or normals (seams) become one; the faces keep
    their order and count.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64

    Returns
    -------
    (m, 3) int64
        Indices into the merged vertices (not into ``vertices``).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(v) == 0:
        return f.copy()
    # positions equal to 1e-8 (trimesh's merge tolerance), as integers; numpy rather than trimesh:
    # importing trimesh costs 0.15-0.9 s, and a built-in instance needs nothing else of it
    key = np.round(v * 1e8).astype(np.int64)
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    return inverse.reshape(-1)[f]


def is_watertight(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """True when, with the vertices welded by position, every edge is shared by exactly two triangles.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    """
    return _is_closed(welded_faces(vertices, faces))


def read_mesh_file(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read any triangle mesh trimesh understands, unprocessed (vertex order and count kept).

    Faces whose winding is inconsistent are re-oriented consistently (:func:`make_winding_consistent`
    on the :func:`welded_faces`, so across texture seams too); the overall orientation is kept as the
    file has it (a room scanned from inside stays inward).

    Returns
    -------
    vertices : (n, 3) float64
    faces : (m, 3) int64

    Raises
    ------
    MissingPackageError
        trimesh needs a package that is not installed for this file (Pillow for an OBJ with texture
        coordinates, on installs without it).
    """
    try:
        return _read_mesh_file(path)
    except ImportError as exc:
        raise MissingPackageError(path, exc) from None


def _read_mesh_file(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
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
        flip = winding_flips(welded_faces(vertices, faces))
        faces[flip] = faces[flip][:, ::-1]
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
    faces = np.asarray(faces, dtype=np.int64)
    flip = winding_flips(faces)
    if not flip.any():
        return faces
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out


def winding_flips(faces: np.ndarray) -> np.ndarray:
    """Which faces :func:`make_winding_consistent` flips.

    Parameters
    ----------
    faces : (m, 3) int64

    Returns
    -------
    (m,) bool
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
        return np.zeros(m, dtype=bool)
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
    return flip
