"""The supporting-plane shortcut changes no entry of the matrix, only the work."""

import dataclasses

import numpy as np
import pytest

from camplace.instance import builtin
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import make_target_points
from camplace.visibility.engine import assemble, compute_chunk, make_task


@pytest.mark.parametrize("name", ["comet-67p-bunker", "comet-flyby"])
def test_shortcut_gives_the_identical_matrix(name: str) -> None:
    inst = builtin(name)
    pts = make_target_points(inst, 2000 if len(inst.frames) == 1 else 3600, seed=5)
    cands = make_candidates("uniform", 96, inst.volume.min_m, inst.volume.max_m, event_aims(inst, 3), seed=6)
    task, scenes = make_task(inst, cands, pts)
    assert task.support[~pts.is_emitter].mean() > 0.2  # the shortcut really applies to many surface rows
    plain = dataclasses.replace(task, support=np.zeros_like(task.support))
    starts = range(0, len(cands), 32)
    a, ca = assemble(task, [compute_chunk(task, scenes, s, min(s + 32, len(cands))) for s in starts])
    b, cb = assemble(plain, [compute_chunk(plain, scenes, s, min(s + 32, len(cands))) for s in starts])
    assert a.shape == b.shape and (a != b).nnz == 0 and np.array_equal(a.indices, b.indices)
    assert {k: v for k, v in ca.items() if k != "cast"} == {k: v for k, v in cb.items() if k != "cast"}
    assert ca["cast"] <= cb["cast"]  # supporting rows inside a room of occluders need no cast at all


@pytest.mark.parametrize("name", ["comet-67p-bunker", "comet-67p-team", "volcanic-eruption"])
def test_enclosing_room_shortcut_gives_the_identical_matrix(name: str, monkeypatch) -> None:
    """Segments from cameras inside the room of occluders (the bunker's corridor) to supporting rows
    are not cast: the same matrix as casting them, and fewer casts where the room encloses."""
    from camplace.visibility import chunk

    inst = builtin(name)
    pts = make_target_points(inst, 2000 if len(inst.frames) == 1 else 3600, seed=5)
    cands = make_candidates("uniform", 96, inst.volume.min_m, inst.volume.max_m, event_aims(inst, 3), seed=6)
    task, scenes = make_task(inst, cands, pts)
    starts = range(0, len(cands), 32)
    a, ca = assemble(task, [compute_chunk(task, scenes, s, min(s + 32, len(cands))) for s in starts])
    monkeypatch.setattr(chunk, "ENCLOSING_MAX_TRIANGLES", 0)
    task2, scenes2 = make_task(inst, cands, pts)
    assert not task2.enclosing_rest
    b, cb = assemble(task2, [compute_chunk(task2, scenes2, s, min(s + 32, len(cands))) for s in starts])
    assert a.shape == b.shape and (a != b).nnz == 0 and np.array_equal(a.indices, b.indices)
    assert np.array_equal(a.data, b.data)
    if name.startswith("comet-67p"):  # the corridor encloses the cameras and the comet
        assert task.enclosing_rest and ca["cast"] < cb["cast"]


def test_enclosing_room_needs_the_camera_inside() -> None:
    """A camera outside a room (or on a wall's plane) is not enclosed; inside by the margin it is."""
    from camplace.visibility.chunk import _cameras_enclosed

    # the unit cube's six faces as planes with outward normals; rows inside: side False (negative)
    planes = np.array([[1, 0, 0, 1], [-1, 0, 0, 0], [0, 1, 0, 1], [0, -1, 0, 0], [0, 0, 1, 1], [0, 0, -1, 0]], float)
    side = np.zeros(6, dtype=bool)
    assert _cameras_enclosed(np.array([[0.5, 0.5, 0.5], [0.1, 0.9, 0.2]]), planes, side, 1.0)
    assert not _cameras_enclosed(np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5]]), planes, side, 1.0)
    assert not _cameras_enclosed(np.array([[1.0, 0.5, 0.5]]), planes, side, 1.0)  # on a wall
    assert not _cameras_enclosed(np.array([[1.0 - 1e-7, 0.5, 0.5]]), planes, side, 1.0)  # within the margin


@pytest.mark.parametrize("name", ["comet-67p-bunker", "comet-flyby", "volcanic-eruption"])
def test_supporting_rows_oracle(name: str) -> None:
    """Rows flagged as supporting really have every target vertex of their frame behind their
    tangent plane, and no other surface row does (every frame: one hull, taken in the target's own
    frame, serves them all)."""
    inst = builtin(name)
    pts = make_target_points(inst, 3000, seed=1)
    cands = make_candidates("uniform", 4, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=2)
    task, _ = make_task(inst, cands, pts)
    surface = ~pts.is_emitter
    assert surface.sum() > 1000 and task.support[surface].any()
    if name.startswith("comet"):  # a comet's hollows: rows whose plane has the target above it
        assert not task.support[surface].all()
    for f in np.unique(pts.frame):
        v, _ = inst.target_world(int(f))
        rows = np.nonzero((pts.frame == f) & surface)[0]
        reach = np.array([np.max((v - pts.positions[i]) @ pts.normals[i]) for i in rows])
        assert np.all(reach[task.support[rows]] <= task.support_tol[f])
        assert np.all(reach[~task.support[rows]] > task.support_tol[f])
    assert not task.support[~surface].any()


def _surface_points(mesh, n: int, seed: int):
    """``n`` points on ``mesh``'s faces with their faces' outward normals, as the matrix's rows."""
    import trimesh

    from camplace.visibility.points import TargetPoints

    pos, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    nrm = np.asarray(mesh.face_normals[face], dtype=np.float64)
    return TargetPoints(np.asarray(pos, dtype=np.float64), nrm, np.zeros(n, dtype=np.int32), np.full(n, 1.0 / n))


def _shapes():
    import trimesh
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("xyz", [20, 35, 50], degrees=True).as_matrix()
    ellipsoid = trimesh.creation.icosphere(subdivisions=4)
    ellipsoid.vertices = (ellipsoid.vertices * [3.0, 1.0, 0.5]) @ rot.T
    dented = trimesh.creation.icosphere(subdivisions=4)
    dented.vertices = dented.vertices * (1.0 - 0.3 * np.exp(-20 * (dented.vertices[:, :1] - 1.0) ** 2))  # a bowl on +x
    rng = np.random.default_rng(4)
    blob = trimesh.convex.convex_hull(rng.normal(size=(400, 3)))
    inst = builtin("comet-67p-bunker")
    comet = trimesh.Trimesh(*inst.target_world(0), process=False)
    return {
        "sphere": trimesh.creation.icosphere(subdivisions=5),  # every row supporting: no early exit
        "ellipsoid": ellipsoid,
        "dented": dented,
        "box": trimesh.creation.box(extents=(2.0, 1.0, 0.5)),  # coplanar facets: ties along the ascent
        "blob": blob,
        "comet": comet,
    }


@pytest.mark.parametrize("shape", ["sphere", "ellipsoid", "dented", "box", "blob", "comet"])
def test_supporting_rows_by_ascent_equal_every_vertex(shape: str) -> None:
    """The ascent along the hull's edges flags exactly the rows that trying every vertex (the
    same products, in numpy) flags, at every thread count."""
    from camplace._cores import using_threads
    from camplace.visibility.engine import supporting_rows

    mesh = _shapes()[shape]
    pts = _surface_points(mesh, 4000, seed=7)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    tol = 1e-9 * float(np.linalg.norm(np.ptp(v, axis=0)))
    n, p = pts.normals, pts.positions
    lim = n[:, 0] * p[:, 0] + n[:, 1] * p[:, 1] + n[:, 2] * p[:, 2] + tol
    dots = n[:, :1] * v[:, 0] + n[:, 1:2] * v[:, 1] + n[:, 2:] * v[:, 2]  # (rows, vertices)
    expected = ~np.any(dots > lim[:, None], axis=1)
    assert 0 < expected.sum()
    for threads in (1, 2):
        with using_threads(threads):
            got = supporting_rows(pts, 0, v, tol)
        assert np.array_equal(got, expected), (shape, threads, int((got != expected).sum()))
    if shape in ("dented", "comet"):
        assert not expected.all()  # rows in a hollow see the target above their plane


def test_supporting_rows_of_a_flat_target_try_every_vertex() -> None:
    """A flat target has no 3D hull: every vertex is tried (the rows facing up support it)."""
    from camplace.visibility.engine import hull_graph, supporting_rows
    from camplace.visibility.points import TargetPoints

    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    assert hull_graph(v) is None
    pos = np.array([[0.5, 0.5, 0.0], [0.2, 0.7, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    pts = TargetPoints(pos, nrm, np.zeros(2, dtype=np.int32), np.full(2, 0.5))
    assert supporting_rows(pts, 0, v, 1e-9).tolist() == [True, False]
