"""A target too small to see (issue 33 item 5): its projected size against analytic oracles, the
``[quality] min_target_px`` cut in the visibility engine, and ``camplace run`` on an instance whose
mesh scale is off by 1,000 (walked in a subprocess: console, ``solution.json``, report)."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from camplace.errors import CamplaceError
from camplace.geometry import look_at
from camplace.instance import builtin_toml, load_instance, parse_instance, save_instance
from camplace.instance.schema import CameraModel, Emitters, Frame, Instance, Light, Mesh, Pose, QualitySpec, Volume
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, make_target_points
from camplace.visibility.footprint import SMALL_TARGET_PX, hull_footprint_px, small_target_warnings, target_footprint_px
from tests._package import subprocess_env

ROOT = Path(__file__).resolve().parents[2]
K = np.array([[200.0, 0.0, 79.5], [0.0, 200.0, 59.5], [0.0, 0.0, 1.0]])


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "camplace", *args], cwd=cwd, env=subprocess_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return proc


# ---------------------------------------------------------------------------------------------------
# the footprint against analytic oracles


def test_cube_face_on_covers_its_front_face() -> None:
    """A 1 m cube 4.5 m in front of the camera, face on: only its front face faces the camera, and
    that square projects to (f * 1 m / 4.5 m)^2 pixels."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    v = np.asarray(box.vertices) + [0.0, 0.0, 5.0]
    area = hull_footprint_px(v, np.zeros((1, 3)), np.eye(3)[None], K)
    assert area[0] == pytest.approx((200.0 / 4.5) ** 2, rel=1e-12)
    # turned away (the camera looks along -z): the cube is behind it and covers nothing
    away = np.diag([-1.0, 1.0, -1.0])
    assert hull_footprint_px(v, np.zeros((1, 3)), away[None], K)[0] == 0.0
    # a camera inside the cube's depth range: the projection is unbounded
    assert hull_footprint_px(v, np.array([[0.0, 0.0, 5.0]]), np.eye(3)[None], K)[0] == np.inf


def test_sphere_seen_from_anywhere_covers_the_tangent_cone() -> None:
    """A sphere of radius r at distance d, aimed at (any pose, world-from-camera rotation by
    look_at): its silhouette is a disc of area pi f^2 r^2 / (d^2 - r^2); the inscribed hull of an
    icosphere covers a little less."""
    r, centre = 0.8, np.array([1.0, 2.0, 0.5])
    v = np.asarray(trimesh.creation.icosphere(subdivisions=4, radius=r).vertices) + centre
    pos = np.array([[3.0, -7.0, 5.0], [1.0, 2.0, 12.0], [-4.0, 2.5, 0.5]])
    rot = look_at(pos, np.broadcast_to(centre, pos.shape))
    d2 = np.sum((pos - centre) ** 2, axis=1)
    disc = np.pi * 200.0**2 * r**2 / (d2 - r**2)
    area = hull_footprint_px(v, pos, rot, K)
    assert np.all(area <= disc) and np.all(area >= 0.995 * disc), area / disc


def test_each_frame_moves_the_hull_with_the_target() -> None:
    """The hull is taken once in the target's frame and moved by each frame's pose: the same areas
    as the hull of each frame's posed mesh."""
    box = trimesh.creation.box(extents=(1.2, 0.3, 0.5))
    inst = dataclasses.replace(
        _sphere_instance(), target=Mesh("slab", np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)),
        frames=(Frame(Pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))), Frame(Pose((0.5, -1.0, 0.3), (30.0, -50.0, 75.0)))),
    )
    rng = np.random.default_rng(0)
    pos = rng.uniform(-6.0, 6.0, (20, 3)) + [0.0, 0.0, 8.0]
    rot = look_at(pos, rng.uniform(-0.5, 0.5, (20, 3)))
    got = target_footprint_px(inst, pos, rot)
    for f in range(2):
        np.testing.assert_allclose(got[:, f], hull_footprint_px(inst.target_world(f)[0], pos, rot, inst.camera.K()), rtol=1e-9)
    assert not np.allclose(got[:, 0], got[:, 1], rtol=0.05)  # the pose matters


# ---------------------------------------------------------------------------------------------------
# [quality] min_target_px in the visibility engine


def _sphere_instance(min_target_px: float = 0.0, frames: tuple = (Frame(Pose((0.0, 0.0, 0.0))),)) -> Instance:
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    target = Mesh("ball", np.asarray(ico.vertices), np.asarray(ico.faces, dtype=np.int64))
    cam = CameraModel(7.18, 5.32, 8.0, 160, 120, 0.1, 60.0)
    return Instance("ball", 2, cam, Volume((-20.0, -20.0, -20.0), (20.0, 20.0, 20.0)), Light((0.0, 0.0, 30.0)), target, (),
                    frames, quality=QualitySpec(min_target_px=min_target_px))


@pytest.mark.parametrize("block_pairs", [1 << 22, 97])
def test_min_target_px_drops_exactly_the_views_too_small(block_pairs, monkeypatch) -> None:
    """With a minimum projected size, the matrix is the plain one with each frame's target rows
    zeroed in the cameras that see that frame's ball smaller, emitter rows untouched, and nothing
    else changed (two frames, the ball moved; also made a few rows at a time)."""
    import camplace.visibility.engine as engine

    monkeypatch.setattr(engine, "_DROP_BLOCK_PAIRS", block_pairs)
    glow = Emitters(np.array([[0.0, 0.0, 0.6], [0.2, 0.0, -0.6]]), np.array([0.5, 0.5]))
    frames = (Frame(Pose((0.0, 0.0, 0.0))), Frame(Pose((4.0, 3.0, -2.0)), emitters=glow))
    plain = _sphere_instance(frames=frames)
    pts = make_target_points(plain, 800, seed=1)
    cands = make_candidates("uniform", 40, plain.volume.min_m, plain.volume.max_m, np.zeros(3), seed=2)
    fp = target_footprint_px(plain, cands.positions, cands.rotations)
    need = float(np.median(fp))
    base = compute_visibility(plain, cands, pts).matrix.toarray()
    cut = compute_visibility(_sphere_instance(need, frames), cands, pts).matrix.toarray()
    expect = base.copy()
    for f in range(2):
        rows = (pts.frame == f) & ~pts.is_emitter
        expect[np.ix_(rows, fp[:, f] < need)] = 0.0
    assert (expect != base).any()  # the cut drops something
    assert (base[np.ix_(pts.is_emitter, fp[:, 1] < need)] > 0).any()  # and must keep emitters that small views see
    np.testing.assert_array_equal(cut, expect)


def test_min_target_px_is_read_written_and_checked(tmp_path) -> None:
    data = builtin_toml("comet-67p-bunker")
    inst = parse_instance({**data, "quality": {"min_target_px": 40}}, "t", Path.cwd())
    assert inst.quality.min_target_px == 40.0
    save_instance(inst, tmp_path / "i.toml", mesh_files=True)
    assert load_instance(tmp_path / "i.toml").quality == inst.quality
    assert parse_instance(data, "t", Path.cwd()).quality.min_target_px == 0.0
    with pytest.raises(CamplaceError, match="quality.min_target_px"):
        parse_instance({**data, "quality": {"min_target_px": -1}}, "t", Path.cwd())


# ---------------------------------------------------------------------------------------------------
# camplace run on a target 1,000 times too small


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    """The bunker instance file with its target mesh read at scale 0.001 (a 0.6 mm comet)."""
    work = tmp_path_factory.mktemp("tiny")
    shutil.copytree(ROOT / "instances" / "comet-67p-bunker_meshes", work / "comet-67p-bunker_meshes")
    text = (ROOT / "instances" / "comet-67p-bunker.toml").read_text()
    line = 'file = "comet-67p-bunker_meshes/target.ply"\n'
    assert line in text
    (work / "tiny.toml").write_text(text.replace(line, line + "scale = 0.001\n"))
    (work / "tiny-min.toml").write_text(text.replace(line, line + "scale = 0.001\n").replace("[target]", "[quality]\nmin_target_px = 25.0\n\n[target]"))
    return work


SIZE = ["--candidates", "60", "--points", "600", "--no-cache"]


def test_run_warns_when_the_target_is_too_small_to_see(tiny) -> None:
    proc = _cli("run", "tiny.toml", "-o", "out", *SIZE, cwd=tiny)
    sol = json.loads((tiny / "out" / "solution.json").read_text())
    assert sol["coverage_fraction"] > 0.5  # the run still counts its points as observed
    found = [w for w in sol["warnings"] if w.startswith("the target is too small to see")]
    assert len(found) == 1 and f"fewer than {SMALL_TARGET_PX:g} px" in found[0]
    assert f"warning: {found[0]}" in proc.stderr
    largest = float(re.search(r"at most ([0-9.e+-]+) px", found[0]).group(1))
    # the chosen cameras' footprints recomputed from the run folder
    inst = load_instance(tiny / "out" / "instance.toml")
    pos = np.array([c["position"] for c in sol["cameras"]])
    rot = np.array([c["rotation"] for c in sol["cameras"]])
    assert largest == pytest.approx(target_footprint_px(inst, pos, rot).max(), rel=1e-2) and largest < SMALL_TARGET_PX
    _cli("report", "out", "--no-sampler-study", "-o", "report.html", cwd=tiny)
    assert "run warning: the target is too small to see" in (tiny / "report.html").read_text()
    # at its real size the same cameras resolve it: no warning
    real = parse_instance(builtin_toml("comet-67p-bunker"), "t", Path.cwd())
    assert target_footprint_px(real, pos, rot).max() > 100 * SMALL_TARGET_PX
    assert small_target_warnings(real, pos, rot) == []


def test_run_with_min_target_px_observes_nothing_of_a_target_too_small(tiny) -> None:
    proc = _cli("run", "tiny-min.toml", "-o", "out-min", *SIZE, cwd=tiny)
    sol = json.loads((tiny / "out-min" / "solution.json").read_text())
    assert sol["objective"] == 0.0 and sol["coverage_fraction"] == 0.0
    assert "warning: no candidate observes any point of the event" in proc.stderr


def test_render_warns_when_every_view_shows_the_target_smaller_than_detectable() -> None:
    from camplace.validation.workflow import _render_warnings

    assert _render_warnings([{"target_px": 0}, {"target_px": 4}, {"target_px": 24}]) != []
    assert "at most 24 px" in _render_warnings([{"target_px": 0}, {"target_px": 24}])[0]
    assert _render_warnings([{"target_px": 0}, {"target_px": int(SMALL_TARGET_PX)}]) == []
