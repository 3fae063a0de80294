"""The report's 3D view of an event built-in (comet-flyby: 36 frames, a coma of emitter points),
checked against a recount from the run folder's own files (visibility.cpm, points.csv, solution.json)."""

from __future__ import annotations

import json

import numpy as np

import camplace
import pytest
import scipy.sparse as sp

from camplace.instance import builtin
from camplace.pipeline import run
from camplace.plotly3d import scene_page
from camplace.report.compare import load_run_data
from camplace.report.run_scene import run_scene


@pytest.fixture(scope="module")
def flyby(tmp_path_factory):
    out = tmp_path_factory.mktemp("flyby") / "run"
    run(builtin("comet-flyby", seed=0), seed=0, candidates=30, points=360, time_limit_s=10, outdir=out)
    return out


def test_event_scene_shows_the_peak_frame_and_the_trajectory(flyby) -> None:
    sol = json.loads((flyby / "solution.json").read_text())
    table = np.loadtxt(flyby / "points.csv", delimiter=",", skiprows=1)
    xyz, normals, frame = table[:, 1:4], table[:, 4:7], table[:, 7].astype(int)
    M = camplace.load_visibility(flyby).tocsc()
    sel = [int(c["candidate"]) for c in sol["cameras"]]
    peak = sol["peak_frame"]
    rows = np.flatnonzero(frame == peak)
    counts = np.asarray((M[:, sel] > 0).sum(axis=1)).ravel()

    rd = load_run_data(flyby)
    scene = run_scene(rd)
    inst = rd.instance
    assert len(inst.frames) == 36 and scene.meta["frame"] == peak == scene.peak_frame
    assert len(scene.cameras) == len(sel) == 3
    assert scene.points == pytest.approx(xyz[rows])
    assert np.array_equal(scene.counts, counts[rows])
    emitters = ~np.any(normals[rows] != 0, axis=1)
    assert emitters.any() and (~emitters).any()  # a coma and the nucleus's surface
    assert np.array_equal(scene.surface, ~emitters)
    # the target is the nucleus at the peak frame: the surface points lie on it (within its bounding box)
    v = scene.target.vertices
    surf = xyz[rows][~emitters]
    assert np.all(surf >= v.min(axis=0) - 1e-9) and np.all(surf <= v.max(axis=0) + 1e-9)
    # the trajectory: one centre per frame, the frame's target bounding-box centre
    assert scene.trajectory.shape == (36, 3) and len(scene.trajectory_labels) == 36
    for f in (0, peak, 35):
        vf = inst.target.transformed(inst.frames[f].target_pose)[0]
        assert scene.trajectory[f] == pytest.approx((vf.min(axis=0) + vf.max(axis=0)) / 2)
    # each frame's label states the observed share of that frame's weight
    w = table[:, 8]
    f = peak
    seen = (frame == f) & (counts > 0)
    share = 100.0 * w[seen].sum() / w[frame == f].sum()
    assert f"{share:.1f} % of the frame's weight observed" in scene.trajectory_labels[f]
    page = scene_page(scene, include_plotlyjs=False)
    d = json.loads(page.split("id='scene3d-data'>", 1)[1].split("</script>", 1)[0])
    assert d["n_cameras"] == 3 and d["trajectory"]["peak"] == peak and len(d["trajectory"]["centres"]) == 36
    assert d["coverage"]["points"] == [int(np.sum(np.minimum(counts[rows], 3) == c)) for c in range(4)]


def test_event_report_holds_the_3d_view(flyby) -> None:
    from camplace.report.build import write_report

    page = write_report(flyby, sampler_study=False, out=flyby / "r.html")
    text = page.read_text()
    d = json.loads(text.split("id='scene3d-data'>", 1)[1].split("</script>", 1)[0])
    sol = json.loads((flyby / "solution.json").read_text())
    assert d["n_cameras"] == len(sol["cameras"]) == 3 and d["frame"] == sol["peak_frame"] and d["n_frames"] == 36
    assert len(text.encode()) < 8_000_000


def test_multiview_counted_rows_weigh_the_objective(tmp_path) -> None:
    """Oracle: the solver's mode_value of the chosen cameras is the weight of the rows the view marks as counted."""
    from camplace.report.run_scene import multiview_counted
    from camplace.solver.api import mode_value
    from tests.report.test_report_html import small_instance

    out = tmp_path / "mv"
    run(small_instance(), seed=2, candidates=40, points=400, mode="multiview", views=2, min_angle_deg=25.0, time_limit_s=2, outdir=out)
    rd = load_run_data(out)
    sol = rd.solution
    sel = sol.selected
    seen = (rd.matrix[:, sel] > 0).toarray()
    pos = rd.candidates.positions[sel]
    for angle in (None, 25.0, 60.0):
        want = mode_value(rd.matrix, rd.weights, sel, mode="multiview", views=2, min_angle_deg=angle,
                          positions=rd.candidates.positions, points=rd.points.positions)
        got = multiview_counted(rd.points.positions, seen, pos, 2, angle)
        assert float(rd.weights[got].sum()) == pytest.approx(want, rel=1e-12, abs=1e-15)
    assert float(rd.weights[multiview_counted(rd.points.positions, seen, pos, 2, 25.0)].sum()) == pytest.approx(sol.objective, rel=1e-9)
    scene = run_scene(rd)
    peak = rd.points.frame == sol.peak_frame
    assert np.array_equal(scene.counted, multiview_counted(rd.points.positions, seen, pos, 2, 25.0)[peak])
    assert any("25 deg apart" in n for n in scene.notes)
