"""Installed systems in ``camplace validate`` (issue 19): the run's objective at the photographed poses,
the photo figure, the pairing of installations, and robust > nominal once installed.

Oracles: the robust run's own out-of-sample check (``solution.json`` ``robust.out_of_sample``, computed
at run time by :mod:`camplace.robust` on its stacked scenario matrix) for the same installations;
an analytic box scene for the photo figure's depth test; hand counts for the per-mode counting.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from camplace.instance import builtin_toml, parse_instance, save_instance
from camplace.validation.cameras import CameraView
from camplace.validation.installed import camera_keys, installation_draws, photo_value, seen_in_photo
from camplace.validation.physical import PhysicalCamera, install_camera, perturb_camera
from camplace.sampling.perturb import OUT_OF_SAMPLE_STREAM
from tests._package import subprocess_env

#: a bunker run where the nominal multiview optimum is fragile (measured: robust minus nominal over
#: 16 installations +0.011, +0.006, +0.007, +0.007, +0.005 for validation seeds 0..4, standard errors
#: about 0.002; docs/robust.md)
RUN = ["--mode", "multiview", "--candidates", "200", "--points", "500", "--seed", "3"]
N_INSTALL = 16


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camplace", *args], cwd=cwd, env=subprocess_env(), capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """A nominal and a robust (0.1 m, 5 deg) run of a small-image bunker, and the [physical] file."""
    root = tmp_path_factory.mktemp("installed")
    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["camera"].update(width_px=160, height_px=120)  # same field of view (what the ray caster uses), cheaper photographs
    save_instance(parse_instance(data, "small", root), root / "bunker.toml", mesh_files=True)
    for name, extra in (("nominal", []), ("robust", ["--pose-error", "0.1,5", "--scenarios", "16"])):
        res = _cli("run", "bunker.toml", "-o", name, *RUN, "--no-cache", *extra, cwd=root)
        assert res.returncode == 0, res.stderr
    (root / "phys.toml").write_text("[physical]\nsigma_position_m = 0.1\nsigma_rotation_deg = 5.0\n")
    return root


@pytest.mark.slow
def test_robust_keeps_more_once_installed(runs) -> None:
    """Validated under the same [physical] errors, the robust system's installed objective is higher,
    and every installation's value is the robust run's own out-of-sample value for it."""
    out = runs / "val"
    res = _cli("validate", "nominal", "robust", "--physical", "phys.toml", "--seed", "3", "--installations", str(N_INSTALL),
               "--threshold", "triangle", "-o", "val", cwd=runs)
    assert res.returncode == 0, res.stderr
    rep = json.loads((out / "validation.json").read_text())["installed"]
    assert rep["available"] and rep["installations"] == N_INSTALL and rep["seed_stream"] == OUT_OF_SAMPLE_STREAM
    nominal, robust = rep["systems"]
    sol_n = json.loads((runs / "nominal" / "solution.json").read_text())
    sol_r = json.loads((runs / "robust" / "solution.json").read_text())
    rob = sol_r["robust"]
    # the robust run's nominal optimum is the nominal run's system, and the systems differ
    assert rob["nominal_solution"]["selected"] == [c["candidate"] for c in sol_n["cameras"]]
    assert nominal["keys"] == [c["candidate"] for c in sol_n["cameras"]] != robust["keys"]
    # oracle: with the run's seed, installation t is scenario t of the run's out-of-sample check
    for mine, name in ((nominal, "nominal"), (robust, "robust")):
        assert mine["objective_settings"]["mode"] == "multiview" and mine["objective_settings"]["views"] == 2
        assert len(mine["objective"]["values"]) == N_INSTALL
        assert np.allclose(mine["objective"]["values"], rob["out_of_sample"][name]["values"][:N_INSTALL], rtol=1e-9, atol=0)
        assert mine["objective"]["mean"] == pytest.approx(np.mean(mine["objective"]["values"]), rel=1e-12)
        # the photo figure: counted on the 500 points of frame 0, a share of their weight
        assert mine["photo_rows"] == 500
        assert len(mine["photo"]["values"]) == N_INSTALL
        assert all(0.0 <= v <= 1.0 for v in mine["photo"]["values"]) and mine["photo"]["mean"] > 0
    # the installed pose error changes what is seen (the installations are not all alike)
    assert np.ptp(nominal["objective"]["values"]) > 0
    assert robust["objective"]["mean"] >= nominal["objective"]["mean"]
    assert robust["objective"]["p10"] >= nominal["objective"]["p10"]
    cmp_ = rep["comparison"]
    assert cmp_["best_objective_mean"] == 2
    paired = cmp_["paired"][0]["objective"]
    assert paired["mean"] == pytest.approx(robust["objective"]["mean"] - nominal["objective"]["mean"], rel=1e-9)
    assert "system 2 (robust) keeps the most once installed" in res.stdout
    assert "system 2 minus system 1: objective +" in res.stdout


@pytest.mark.slow
def test_same_seed_same_installed_record(runs) -> None:
    from camplace.validation.workflow import validate_runs

    phys = PhysicalCamera(sigma_position_m=0.1, sigma_rotation_deg=5.0, noise_sigma=0.01)
    reps = [validate_runs([runs / "robust"], runs / name, physical=phys, seed=8, installations=2) for name in ("a", "b")]
    def figures(rep):  # the camera records without the photo paths (each report has its own folder)
        return [{k: v for k, v in c.items() if k not in ("photo", "background")} for c in rep.cameras]

    assert reps[0].installed == reps[1].installed and figures(reps[0]) == figures(reps[1])
    assert len(reps[0].installed["systems"][0]["objective"]["values"]) == 2 and len(reps[0].installed["systems"][0]["photo"]["values"]) == 2
    other = validate_runs([runs / "robust"], runs / "c", physical=phys, seed=9, installations=2)
    assert [c["pose_error_m"] for c in other.cameras] != [c["pose_error_m"] for c in reps[0].cameras]


def test_bad_installations_is_one_line_exit_2(runs) -> None:
    res = _cli("validate", "nominal", "--installations", "0", "-o", "bad", cwd=runs)
    assert res.returncode == 2 and res.stderr.strip().startswith("error: --installations") and "Traceback" not in res.stderr


# ---------------------------------------------------------------------------------------------------
# draws and pairing


def test_shared_camera_installed_identically_and_as_physical() -> None:
    """Keys are candidate indices: a camera in two systems gets the same installations; installation t
    is perturb_camera's draw t from the candidate's out-of-sample stream."""
    phys = PhysicalCamera(sigma_position_m=0.1, sigma_rotation_deg=5.0)
    cam = CameraView("c", [1.0, 2.0, 3.0], np.eye(3), np.eye(3), 10, 10)
    a = installation_draws(4, camera_keys([{"candidate": 7}, {"candidate": 2}], 1), 3)
    b = installation_draws(4, camera_keys([{"candidate": 9}, {"candidate": 7}], 2), 3)
    assert np.array_equal(a[0], b[1]) and not np.array_equal(a[1], b[0])
    rng = np.random.default_rng(np.random.SeedSequence(4, spawn_key=(OUT_OF_SAMPLE_STREAM, 7)))
    for t in range(3):
        ref = perturb_camera(cam, phys, rng)
        got = install_camera(cam, phys, a[0, t])
        assert np.allclose(got.position, ref.position, atol=1e-12) and np.allclose(got.rotation, ref.rotation, atol=1e-12)
    # cameras without a candidate index get keys of their own, per system and slot
    assert camera_keys([{}, {}], 1) != camera_keys([{}, {}], 2)


# ---------------------------------------------------------------------------------------------------
# the photo figure


def test_depth_test_drops_the_far_side_of_the_target() -> None:
    """A box seen face on: points on its front face are seen; points on its back face project inside
    the silhouette too but lie behind the surface the photo shows."""
    from camplace.validation.render import render_view, target_scene
    from camplace.validation.workflow import box_mesh

    scene = target_scene(*box_mesh([-0.5, -0.5, 4.5], [0.5, 0.5, 5.5]))  # 1 m cube, 5 m in front of the camera
    K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])
    cam = CameraView("c", [0.0, 0.0, 0.0], np.eye(3), K, 160, 120)  # looking along +z
    r = render_view(cam, scene)
    xy = np.array([[x, y] for x in (-0.3, 0.0, 0.25) for y in (-0.2, 0.1)])
    front = np.column_stack([xy, np.full(len(xy), 4.5)])
    back = np.column_stack([xy, np.full(len(xy), 5.5)])
    outside = np.array([[1.5, 0.0, 4.5]])  # beside the box: not in the target
    pts = np.vstack([front, back, outside])
    seen = seen_in_photo(cam, r.target_mask, r.depth, pts)
    assert seen[: len(xy)].all() and not seen[len(xy):].any()
    no_depth = seen_in_photo(cam, r.target_mask, r.depth, pts, depth_tolerance_px=1e9)
    assert no_depth[: 2 * len(xy)].all() and not no_depth[-1]  # without the depth test the far side would count


def test_photo_value_counts_per_mode() -> None:
    seen = np.array([[1, 1, 0, 0], [1, 0, 1, 0], [1, 0, 0, 0]], dtype=bool)  # 3 cameras x 4 points
    w = np.array([0.1, 0.2, 0.3, 0.4])
    assert photo_value(seen, w, "maxcover", 2) == pytest.approx(0.6)
    assert photo_value(seen, w, "multiview", 2) == pytest.approx(0.1)
    assert photo_value(seen, w, "multiview", 1) == pytest.approx(0.6)
