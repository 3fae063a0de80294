"""The validation verbs end to end on a small run folder (made without the solver)."""

from __future__ import annotations

import copy
import csv
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import camplace.cli
from camplace.instance import builtin_toml, parse_instance, save_instance
from camplace.solution import Solution, camera_record
from camplace.sampling import make_candidates
from camplace.validation.render import read_image, render_view, scene_for_frame
from camplace.validation.cameras import CameraSet


@pytest.fixture
def cli(monkeypatch):
    monkeypatch.setattr(camplace.cli, "VERB_MODULES", ("camplace.validation.cli", "camplace.report.cli"))  # export is a report verb
    return camplace.cli.main


def small_instance(frames: int = 1, extra: dict | None = None):
    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["camera"].update(width_px=160, height_px=120)
    data["target"]["subdivisions"] = 2
    data["frames"] = [{"weight": 1.0, "position_m": [12.0 + 0.2 * i, 1.5, 1.5]} for i in range(frames)]
    if extra:
        data.update(extra)
    return parse_instance(data, "test", Path.cwd())


def make_run(outdir: Path, frames: int = 1, chosen=(0, 1, 2), seed: int = 5, extra: dict | None = None) -> Path:
    """instance.toml, candidates.csv and solution.json as 'camplace run' writes them (cameras chosen by hand)."""
    inst = small_instance(frames, extra)
    outdir.mkdir(parents=True, exist_ok=True)
    save_instance(inst, outdir / "instance.toml", mesh_files=True)
    aim = inst.target_centre(0)
    cands = make_candidates("uniform", 12, (9.0, 0.5, 0.5), (11.0, 2.5, 2.5), aim, seed=seed)
    cands.save(outdir / "candidates.csv")
    sol = Solution(
        status="optimal", objective=0.5, bound=0.5, gap=0.0, k=len(chosen), seed=seed, sampler="uniform",
        n_candidates=len(cands), n_points=100, coverage_fraction=0.5, timings_s={}, versions={},
        cameras=[camera_record(inst, cands, j) for j in chosen], instance=inst.name, engine="test",
    )
    sol.save(outdir)
    return outdir


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return make_run(tmp_path_factory.mktemp("run") / "out")


def test_render_writes_images_backgrounds_masks(cli, run_dir, tmp_path, capsys) -> None:
    out = tmp_path / "render"
    assert cli(["render", str(run_dir), "-o", str(out)]) == 0
    manifest = json.loads((out / "render.json").read_text())
    assert len(manifest["images"]) == 3
    inst = small_instance()
    sol = Solution.load(run_dir)
    cams = CameraSet.from_solution(sol)
    scene = scene_for_frame(inst, 0)
    for n, cam in enumerate(cams.cameras, start=1):
        stem = f"ecomet-67p-bunker.1.camera_{n}"
        assert cam.name == stem
        img = cv2.imread(str(out / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        bg = cv2.imread(str(out / f"{stem}.background.png"), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(out / f"{stem}.mask.png"), cv2.IMREAD_UNCHANGED)
        assert img.shape == (120, 160) and img.dtype == np.uint8
        ref = render_view(cam, scene)
        np.testing.assert_array_equal(mask > 0, ref.target_mask)
        assert ref.target_px > 0
        # outside the target (and its shadow) the background image equals the image
        same = ~ref.target_mask
        assert np.mean(img[same] == bg[same]) > 0.8
    assert "3 views" in capsys.readouterr().out
    # 16-bit, frame selection and the frame suffix
    multi = make_run(tmp_path / "multi", frames=3)
    assert cli(["render", str(multi), "--frames", "0,2", "--16bit", "--experiment", "X", "--system", "4"]) == 0
    names = sorted(p.name for p in (multi / "render").glob("*.png"))
    assert "eX.4.camera_1.frame_0.png" in names and "eX.4.camera_3.frame_2.mask.png" in names
    assert not any(".frame_1." in n for n in names) and len(names) == 3 * 2 * 3
    assert cv2.imread(str(multi / "render" / "eX.4.camera_1.frame_0.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16


def test_render_bad_frames_is_one_line_error(cli, run_dir, capsys) -> None:
    assert cli(["render", str(run_dir), "--frames", "7"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --frames: frame 7 does not exist") and err.count("\n") == 1


def test_validate_emulated_perfect_camera_agrees_with_prediction(cli, run_dir, tmp_path) -> None:
    out = tmp_path / "val"
    assert cli(["validate", str(run_dir), "-o", str(out), "--threshold", "triangle"]) == 0
    rep = json.loads((out / "validation.json").read_text())
    assert len(rep["cameras"]) == 3 and rep["settings"]["physical"]["sigma_position_m"] == 0.0
    for c in rep["cameras"]:
        assert c["pose_error_m"] == 0.0
        # a perfect camera detects what the detection on the render predicts (target and cast shadow alike)
        assert c["detected_px"] == c["predicted_px"] and c["iou"] == 1.0 and c["inside_fraction"] == 1.0
        assert c["predicted_intensity"] == c["detected_intensity"]
    rows = list(csv.DictReader((out / "photos" / "manifest.csv").read_text().splitlines()))
    assert [r["camera"] for r in rows] == [c["name"] for c in rep["cameras"]]
    # the emulated photos can be validated again as real photographs (same numbers)
    out2 = tmp_path / "val2"
    assert cli(["validate", str(run_dir), "--photos", str(out / "photos"), "-o", str(out2), "--threshold", "triangle"]) == 0
    rep2 = json.loads((out2 / "validation.json").read_text())
    for a, b in zip(rep["cameras"], rep2["cameras"]):
        assert (a["iou"], a["detected_px"]) == (b["iou"], b["detected_px"])


def _median_over_views(cams: list[dict], key: str, min_target_px: int = 500) -> float:
    vals = [c[key] for c in cams if c["target_px"] >= min_target_px]
    assert vals and all(v is not None for v in vals)
    return float(np.median(vals))


def test_validate_perfect_camera_default_settings_like_for_like(cli, run_dir, tmp_path, capsys) -> None:
    """Default detection (Otsu, 5 px morphology), no [physical]: the photos' detections equal the predictions."""
    out = tmp_path / "val"
    assert cli(["validate", str(run_dir), "--random-systems", "3", "-o", str(out)]) == 0
    rep = json.loads((out / "validation.json").read_text())
    cams = rep["cameras"]
    big = [c for c in cams if c["target_px"] >= 500]
    assert len(cams) == 12 and len(big) >= 5
    for c in big:
        assert c["iou"] >= 0.98 and c["inside_fraction"] >= 0.98, c["name"]
    assert _median_over_views(cams, "iou") >= 0.98 and _median_over_views(cams, "inside_fraction") >= 0.98
    # the second figure: against the target mask alone (here Otsu keeps the cast shadow and drops dark faces)
    inst = small_instance()
    cam = CameraSet.from_solution(Solution.load(run_dir)).cameras[0]
    target = render_view(cam, scene_for_frame(inst, 0)).target_mask
    from camplace.validation.detect import detect_target

    det = detect_target(read_image(out / "photos" / f"{cam.name}.png"), read_image(out / "photos" / f"{cam.name}.background.png"))
    c0 = cams[0]
    assert c0["name"] == cam.name and c0["target_px"] == int(target.sum())
    inter = int(np.count_nonzero(target & det.mask))
    assert c0["iou_target"] == pytest.approx(inter / np.count_nonzero(target | det.mask))
    assert c0["inside_fraction_target"] == pytest.approx(inter / det.area_px)
    assert c0["perfect_iou_target"] == pytest.approx(c0["iou_target"])
    # the summary block: medians over the views with >= 500 target px, nothing lost against a perfect camera
    g = rep["agreement"]
    assert g["n_views"] == len(big) and g["min_target_px"] == 500
    assert g["like_for_like"]["iou_median"] == pytest.approx(_median_over_views(cams, "iou"))
    assert g["like_for_like"]["iou_drop"] == 0.0 and g["like_for_like"]["inside_fraction_drop"] == 0.0
    assert g["target_mask"]["iou_median"] == pytest.approx(_median_over_views(cams, "iou_target"))
    assert g["target_mask"]["iou_drop"] == pytest.approx(0.0, abs=1e-12)
    text = capsys.readouterr().out
    assert "against the prediction" in text and "against the target mask" in text


def test_validate_placement_error_lowers_the_figures(cli, tmp_path, capsys) -> None:
    """The instance's [physical] placement error: both like-for-like medians fall, more for a larger error, and the report says by how much."""
    medians = []
    for level, (sp, sr) in enumerate([(0.0, 0.0), (0.02, 0.5), (0.1, 3.0)]):
        run = make_run(tmp_path / f"run{level}", extra={"physical": {"sigma_position_m": sp, "sigma_rotation_deg": sr}})
        out = tmp_path / f"val{level}"
        assert cli(["validate", str(run), "--random-systems", "3", "-o", str(out)]) == 0
        rep = json.loads((out / "validation.json").read_text())
        assert rep["settings"]["physical"]["sigma_position_m"] == sp
        cams = rep["cameras"]
        iou, inside = _median_over_views(cams, "iou"), _median_over_views(cams, "inside_fraction")
        g = rep["agreement"]["like_for_like"]
        assert g["iou_median"] == pytest.approx(iou) and g["inside_fraction_median"] == pytest.approx(inside)
        assert g["iou_drop"] == pytest.approx(1.0 - iou) and g["inside_fraction_drop"] == pytest.approx(1.0 - inside)
        assert f"drop {1.0 - iou:.3f} / {1.0 - inside:.3f}" in capsys.readouterr().out
        medians.append((iou, inside))
    assert medians[0] == (1.0, 1.0)
    assert medians[0][0] > medians[1][0] + 0.05 > medians[2][0] + 0.1, medians
    assert medians[0][1] > medians[1][1] + 0.05 > medians[2][1] + 0.1, medians


def test_validate_with_physical_errors_and_several_systems(cli, run_dir, tmp_path) -> None:
    run2 = make_run(tmp_path / "run2", chosen=(3, 4, 5))
    phys = tmp_path / "phys.toml"
    phys.write_text("[physical]\nsigma_position_m = 0.05\nsigma_rotation_deg = 1.0\nnoise_sigma = 0.005\ndefocus_radius_px = 1.0\n")
    out = tmp_path / "val"
    args = ["validate", str(run_dir), str(run2), "--physical", str(phys), "--random-systems", "3", "--seed", "2", "-o", str(out)]
    assert cli(args) == 0
    rep = json.loads((out / "validation.json").read_text())
    assert [s["system"] for s in rep["systems"]] == [1, 2, 3, 4, 5] and len(rep["cameras"]) == 15
    assert rep["across"]["n_systems"] == 5
    assert 0.0 <= rep["across"]["kde_overlap_pct"] <= 100.0
    assert -1.0 <= rep["across"]["spearman_rho"] <= 1.0
    assert all(c["pose_error_m"] > 0 for c in rep["cameras"])
    for fig in ("heatmap_intensity.png", "heatmap_coverage.png", "kde_scores.png"):
        assert fig in rep["figures"] and (out / fig).exists()
    assert np.array(rep["heatmaps"]["coverage_difference"]).shape == (15, 15)
    # same seed, same report
    out_b = tmp_path / "val_b"
    assert cli(args[:-1] + [str(out_b)]) == 0
    rep_b = json.loads((out_b / "validation.json").read_text())
    assert [c["iou"] for c in rep_b["cameras"]] == [c["iou"] for c in rep["cameras"]]


def test_validate_manifest_photos_and_errors(cli, run_dir, tmp_path, capsys) -> None:
    photos = tmp_path / "photos"
    photos.mkdir()
    sol = Solution.load(run_dir)
    cams = CameraSet.from_solution(sol).cameras
    scene = scene_for_frame(small_instance(), 0)
    from camplace.validation.render import write_png

    write_png(photos / "p1.png", render_view(cams[0], scene).image)
    (photos / "list.csv").write_text(f"camera,photo,background\n{cams[0].name},p1.png,\n")
    out = tmp_path / "val"
    assert cli(["validate", str(run_dir), "--photos", str(photos), "--manifest", str(photos / "list.csv"), "-o", str(out), "--morph-px", "0"]) == 0
    rep = json.loads((out / "validation.json").read_text())
    assert [c["name"] for c in rep["cameras"]] == [cams[0].name] and rep["cameras"][0]["background"] is None
    (photos / "bad.csv").write_text("camera,photo\nnobody,p1.png\n")
    assert cli(["validate", str(run_dir), "--photos", str(photos), "--manifest", str(photos / "bad.csv"), "-o", str(out)]) == 2
    assert "camera 'nobody' is not one of the cameras" in capsys.readouterr().err
    assert cli(["validate", "--cameras", str(tmp_path / "none.json"), "--photos", str(photos), "-o", str(out)]) == 2
    assert "--target: required" in capsys.readouterr().err
    assert cli(["validate", "-o", str(out)]) == 2
    assert cli(["validate", str(run_dir), "--threshold", "lots", "-o", str(out)]) == 2
    assert "--threshold" in capsys.readouterr().err


def test_export_physical_and_simulation(cli, run_dir, tmp_path) -> None:
    tr = tmp_path / "lab.toml"
    tr.write_text(
        "[transform]\nmethod = \"scale\"\nsim_extent_m = [30.0, 3.0, 3.0]\nphys_extent_m = [15.0, 3.0, 3.0]\n"
        "reference_m = [1.0, 2.0, 0.0]\n"
    )
    out = tmp_path / "exp"
    assert cli(["export", str(run_dir), "--frame", "physical", "--transform", str(tr), "-o", str(out)]) == 0
    sol = Solution.load(run_dir)
    rows = list(csv.DictReader((out / "placement.physical.csv").read_text().splitlines()))
    data = json.loads((out / "placement.physical.json").read_text())
    assert len(rows) == 3 and data["frame"] == "physical"
    for row, cam in zip(rows, sol.cameras):
        x, y, z = cam["position"]
        assert float(row["x_m"]) == pytest.approx(1.0 + 0.5 * x)
        assert float(row["y_m"]) == pytest.approx(2.0 + y) and float(row["z_m"]) == pytest.approx(z)
        ax, ay, az = cam["aim"]
        assert float(row["aim_x_m"]) == pytest.approx(1.0 + 0.5 * ax)
    assert cli(["export", str(run_dir), "--frame", "simulation", "-o", str(out)]) == 0
    sim = list(csv.DictReader((out / "placement.simulation.csv").read_text().splitlines()))
    assert [float(r["x_m"]) for r in sim] == pytest.approx([c["position"][0] for c in sol.cameras])
    # no [transform] anywhere: lab coordinates asked for are a one-line error naming the fix ...
    assert cli(["export", str(run_dir), "--frame", "physical", "-o", str(tmp_path / "phys")]) == 2
    assert not (tmp_path / "phys").exists()
    # ... and plain export writes the placement in the simulation frame (tests/test_cli_paths.py)
    assert cli(["export", str(run_dir), "-o", str(tmp_path / "plain")]) == 0
    assert (tmp_path / "plain" / "placement.simulation.csv").read_text() == (out / "placement.simulation.csv").read_text()


def test_verbs_register_without_heavy_imports() -> None:
    code = (
        "import sys, argparse; import camplace.validation.cli as c; "
        "p = argparse.ArgumentParser(); s = p.add_subparsers(); v = c.register(s, lambda p: None); "
        "assert sorted(v) == ['import-cameras', 'render', 'validate'], v; "
        "assert 'cv2' not in sys.modules and 'embreex' not in sys.modules, 'heavy import'"
    )
    src = str(Path(camplace.cli.__file__).resolve().parents[1])
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": src})
    assert res.returncode == 0, res.stderr


def test_emulated_photos_read_back_as_written(cli, run_dir, tmp_path) -> None:
    out = tmp_path / "val"
    assert cli(["validate", str(run_dir), "-o", str(out)]) == 0
    sol = Solution.load(run_dir)
    cam = CameraSet.from_solution(sol).cameras[0]
    photo = read_image(out / "photos" / f"{cam.name}.png")
    ref = render_view(cam, scene_for_frame(small_instance(), 0)).image
    np.testing.assert_allclose(photo, np.clip(ref, 0, 1), atol=0.5 / 255 + 1e-6)


def test_validate_cameras_mode_box_and_mesh_targets(cli, tmp_path) -> None:
    """Photos of a lit box on black: detection (threshold alone) matches the ray-cast box mask, for box: and mesh targets.

    The triangle threshold: the box's faces have three grey levels (lit at two angles, ambient only)
    that Otsu's two-class split would cut between (one face or two dropped).
    """
    import trimesh

    from camplace.sampling import look_at
    from camplace.validation.cameras import CameraView
    from camplace.validation.render import RenderScene, write_png
    from camplace.validation.workflow import box_mesh

    lo, hi = np.array([-0.2, -0.1, 0.0]), np.array([0.2, 0.1, 0.3])
    v, f = box_mesh(lo, hi)
    pos = np.array([[1.5, -1.0, 0.8], [-1.2, -1.3, 0.5]])
    R = look_at(pos, np.tile((lo + hi) / 2, (2, 1)))
    K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    cams = CameraSet(tuple(CameraView(f"v{i}", pos[i], R[i], K, 320, 240, image=f"shot{i}.jpg.png") for i in range(2)))
    cams.save(tmp_path / "cameras.json")
    photos = tmp_path / "photos"
    lit = RenderScene.build((v, f), (), [2.0, -3.0, 4.0])
    for i, cam in enumerate(cams.cameras):
        write_png(photos / f"shot{i}.jpg.png", render_view(cam, lit).image)
    trimesh.Trimesh(v, f, process=False).export(tmp_path / "box.ply")
    for target in ("box:-0.2,-0.1,0,0.2,0.1,0.3", str(tmp_path / "box.ply")):
        out = tmp_path / ("val_" + target[:3])
        assert cli(["validate", "--cameras", str(tmp_path / "cameras.json"), "--target", target, "--photos", str(photos),
                    "--morph-px", "0", "--threshold", "triangle", "-o", str(out)]) == 0
        rep = json.loads((out / "validation.json").read_text())
        assert [c["name"] for c in rep["cameras"]] == ["v0", "v1"]
        for c in rep["cameras"]:
            assert c["iou"] > 0.99 and c["inside_fraction"] > 0.99 and c["background"] is None
        assert rep["settings"]["target"] == target
    assert cli(["validate", "--cameras", str(tmp_path / "cameras.json"), "--target", "box:1,2,3", "--photos", str(photos), "-o", str(out)]) == 2
