"""camplace.plotly3d: frusta, depths and decimation against analytic answers; the page's data and size."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from camplace.errors import CamplaceError
from camplace.plotly3d import (
    COVERAGE_CLASSES,
    MAX_POINTS,
    MAX_TARGET_FACES,
    PAGE_CSP,
    Scene3D,
    SceneCamera,
    SceneMesh,
    decimate_mesh,
    frustum_corners,
    reach_depth,
    require_plotly,
    scene_fragment,
    scene_page,
)

K = np.array([[500.0, 0.0, 300.0], [0.0, 480.0, 260.0], [0.0, 0.0, 1.0]])  # principal point off centre


def scene_json(html_text: str, div_id: str = "scene3d") -> dict:
    m = re.search(rf"<script type='application/json' id='{div_id}-data'>(.*?)</script>", html_text, re.S)
    assert m is not None
    return json.loads(m.group(1))


def camera(label: str = "cam", seed: int = 0, depth: float = 3.0) -> SceneCamera:
    rng = np.random.default_rng(seed)
    return SceneCamera(label, rng.normal(size=3), Rotation.random(random_state=seed).as_matrix(), K, 640, 480, near_m=0.2, depth_m=depth)


def test_frustum_corners_project_to_the_image_corners() -> None:
    """Oracle: the pinhole projection u = K R^T (X - C) / z of each corner."""
    for seed in range(5):
        cam = camera(seed=seed)
        for depth in (0.2, 1.0, 7.5):
            X = frustum_corners(cam, depth)
            local = (X - cam.position) @ cam.rotation  # camera frame
            assert local[:, 2] == pytest.approx(np.full(4, depth))
            uv = (local @ K.T)[:, :2] / local[:, 2:3]
            assert uv == pytest.approx(np.array([[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]]), abs=1e-9)


def test_reach_depth_analytic() -> None:
    eye = np.eye(3)  # looking along +z
    pts = np.array([[0.0, 0.0, 1.0], [3.0, -1.0, 5.0], [0.0, 2.0, 2.0]])
    assert reach_depth(np.zeros(3), eye, pts, margin=0.0) == pytest.approx(5.0)
    assert reach_depth(np.zeros(3), eye, pts, margin=0.1) == pytest.approx(5.5)
    assert reach_depth(np.zeros(3), eye, pts, far_m=4.0) == pytest.approx(4.0)
    # everything behind: the distance to the centroid, then the margin
    behind = pts * np.array([1.0, 1.0, -1.0])
    assert reach_depth(np.zeros(3), eye, behind, margin=0.0) == pytest.approx(np.linalg.norm(behind.mean(axis=0)))
    # always beyond the near face
    assert reach_depth(np.zeros(3), eye, np.array([[0.0, 0.0, 0.05]]), near_m=0.1) > 0.1


def test_decimate_mesh_keeps_a_sphere_within_its_cells() -> None:
    m = trimesh.creation.icosphere(subdivisions=5)  # 20,480 faces, radius 1
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    same_v, same_f = decimate_mesh(v, f, len(f))
    assert same_f.shape == f.shape and np.array_equal(same_f, f) and np.array_equal(same_v, v)
    for limit in (5000, 800):
        dv, df = decimate_mesh(v, f, limit)
        assert limit / 8 <= len(df) <= limit
        assert df.min() >= 0 and df.max() < len(dv) and len(np.unique(df)) == len(dv)
        assert np.all((df[:, 0] != df[:, 1]) & (df[:, 1] != df[:, 2]) & (df[:, 0] != df[:, 2]))
        r = np.linalg.norm(dv, axis=1)
        # cluster means of points on the unit sphere lie inside it, close to the surface
        assert r.max() <= 1.0 + 1e-12 and r.min() > 0.85
        # still a closed surface around the centre: normals point outwards on average
        tri = dv[df]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert np.mean(np.einsum("ij,ij->i", n, tri.mean(axis=1)) > 0) > 0.95
    again = decimate_mesh(v, f, 800)
    assert np.array_equal(again[1], decimate_mesh(v, f, 800)[1])


def small_scene(n: int = 500, seed: int = 1, **kw) -> Scene3D:
    rng = np.random.default_rng(seed)
    m = trimesh.creation.icosphere(subdivisions=2)
    pts = rng.normal(size=(n, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    counts = rng.integers(0, 6, size=n)
    return Scene3D(title=kw.pop("title", "t"), cameras=(camera("a", 1), camera("b", 2), camera("c", 3)),
                   target=SceneMesh("ball", np.asarray(m.vertices), np.asarray(m.faces)),
                   occluders=(SceneMesh("wall", np.array([[2.0, -2, -2], [2, 2, -2], [2, 2, 2.0]]), np.array([[0, 1, 2]])),),
                   points=pts, counts=counts, weights=rng.random(n), **kw)


def test_data_tag_holds_the_cameras_and_the_coverage() -> None:
    s = small_scene(n=500)
    d = scene_json(scene_fragment(s))
    assert d["n_cameras"] == 3 and [c["label"] for c in d["cameras"]] == ["a", "b", "c"]
    cov = d["coverage"]
    assert cov["classes"] == list(COVERAGE_CLASSES)
    cls = np.minimum(s.counts, 3)
    assert cov["points"] == [int(np.sum(cls == c)) for c in range(4)]
    w = s.weights
    assert cov["weight_share"] == pytest.approx([w[cls == c].sum() / w.sum() for c in range(4)])
    assert cov["n_drawn"] == 500 and cov["index"] == list(range(500)) and cov["count"] == s.counts.tolist()
    assert d["target"] == {"name": "ball", "faces": 320, "faces_drawn": 320}
    assert d["occluders"] == [{"name": "wall", "faces": 1, "faces_drawn": 1}]


def test_points_beyond_the_limit_are_a_seeded_subset() -> None:
    s = small_scene(n=2000)
    a = scene_json(scene_fragment(s, max_points=300, seed=5))["coverage"]
    b = scene_json(scene_fragment(s, max_points=300, seed=5))["coverage"]
    c = scene_json(scene_fragment(s, max_points=300, seed=6))["coverage"]
    assert a["index"] == b["index"] and a["index"] != c["index"]
    idx = np.array(a["index"])
    assert len(idx) == 300 == a["n_drawn"] and np.all(np.diff(idx) > 0) and idx.max() < 2000
    assert a["count"] == s.counts[idx].tolist()
    assert a["n_points"] == 2000 and sum(a["points"]) == 2000  # the histogram is over every point


def test_user_strings_cannot_leave_their_script_or_markup() -> None:
    evil = "x</script><img src=http://e/>&'\""
    s = small_scene(title=evil)
    s = Scene3D(title=evil, cameras=(SceneCamera(evil, np.zeros(3), np.eye(3), K, 640, 480),), target=SceneMesh(evil, s.target.vertices, s.target.faces),
                points=s.points, counts=s.counts)
    frag = scene_fragment(s, include_plotlyjs=False)
    assert "</script><img" not in frag and "<img" not in frag
    data_text = re.search(r"<script type='application/json' id='scene3d-data'>(.*?)</script>", frag, re.S).group(1)
    assert "<" not in data_text and ">" not in data_text and "&" not in data_text
    assert scene_json(frag)["title"] == evil and scene_json(frag)["cameras"][0]["label"] == evil
    page = scene_page(s, include_plotlyjs=False)
    assert f"<title>{'x&lt;/script&gt;'}" in page and f'content="{PAGE_CSP}"' in page


def test_a_large_scene_stays_under_8_mb() -> None:
    m = trimesh.creation.icosphere(subdivisions=7)  # 327,680 faces
    rng = np.random.default_rng(0)
    n = 150_000
    pts = rng.normal(size=(n, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    ground = trimesh.creation.box(extents=(50.0, 50.0, 0.1)).subdivide().subdivide().subdivide().subdivide().subdivide().subdivide()
    s = Scene3D(title="big", cameras=tuple(camera(f"c{i}", i) for i in range(8)),
                target=SceneMesh("ball", np.asarray(m.vertices), np.asarray(m.faces)),
                occluders=(SceneMesh("ground", np.asarray(ground.vertices) - [0, 0, 2], np.asarray(ground.faces)),),
                points=pts, counts=rng.integers(0, 5, size=n))
    page = scene_page(s)
    assert len(page.encode()) < 8_000_000
    d = scene_json(page)
    assert d["target"]["faces"] == 327_680 and 0 < d["target"]["faces_drawn"] <= MAX_TARGET_FACES
    assert d["occluders"][0]["faces"] == len(ground.faces) > d["occluders"][0]["faces_drawn"]
    assert d["coverage"]["n_drawn"] == MAX_POINTS and d["coverage"]["n_points"] == n


def test_mismatched_arrays_and_missing_plotly_are_one_line_errors(monkeypatch) -> None:
    with pytest.raises(CamplaceError, match="3 points but 2 coverage counts"):
        Scene3D(title="t", cameras=(), points=np.zeros((3, 3)), counts=[0, 1])
    monkeypatch.setitem(sys.modules, "plotly", None)
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)
    with pytest.raises(CamplaceError) as exc:
        require_plotly()
    assert str(exc.value) == "the 3D view needs plotly (part of the report extra): pip install 'camplace[report]'"
