"""``validate`` on the night side (issue 33 item 6): with ``[quality] require_light`` the photographs'
detection and the photo figure count only what the instance can observe.

A 1 m sphere in dark space, cameras 6-8 m away on +x. Lit from +x (day) every camera sees its lit
face; lit from -x (night) every camera sees only the unlit hemisphere, which the renderer still
draws at its ambient level: against black space Otsu's threshold then falls to 0 and, before the
fix, the whole dark outline counted as detected, so the photo figure (0.5) beat the ray cast (0).
Oracles: the ray cast of the same points at the same poses (``objective_frame``) and the renderer's
own shading (a target pixel is lit when it is brighter than the ambient term).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from camplace.geometry import look_at
from camplace.instance import parse_instance
from camplace.validation.cameras import CameraView
from camplace.validation.detect import DetectionSettings, detect_target
from camplace.validation.physical import PhysicalCamera, emulate_shots, unlit_level
from camplace.validation.render import RenderSettings, quantise, render_view, scene_for_frame
from tests._package import subprocess_env


INSTANCE = """schema_version = 1
name = "{name}"
k = 2

[camera]
sensor_width_mm = 7.18
sensor_height_mm = 5.32
focal_length_mm = 8.0
width_px = 160
height_px = 120
near_m = 0.1
far_m = 40.0

[volume]
min_m = [6.0, -0.5, -0.5]
max_m = [8.0, 0.5, 0.5]

[light]
position_m = [{light_x}, 0.0, 0.0]

[quality]
max_incidence_deg = 80.0
require_light = true

[target]
name = "ball"
shape = "sphere"
radius_m = 0.5
subdivisions = 3

[[frames]]
position_m = [0.0, 0.0, 0.0]
"""


def _instance(name: str, light_x: float):
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib

    return parse_instance(tomllib.loads(INSTANCE.format(name=name, light_x=light_x)), name, Path.cwd())


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "camplace", *args], cwd=cwd, env=subprocess_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return proc


def _view(inst, position) -> CameraView:
    pos = np.asarray(position, dtype=np.float64)
    rot = look_at(pos[None], inst.target_centre(0)[None])[0]
    return CameraView("c", pos, rot, inst.camera.K(), inst.camera.width_px, inst.camera.height_px)


def test_a_dark_view_detects_nothing_with_the_unlit_floor() -> None:
    """The night side against dark space: a two-level image (ambient target, black sky) whose Otsu
    threshold is 0. Without a floor the whole dark outline is detected; with the unlit floor of the
    camera that took it (perfect, then noisy and over-exposed) nothing is, while the same camera
    still detects the lit face of the day side."""
    night, day = _instance("night", -100.0), _instance("day", 100.0)
    settings = RenderSettings()
    cam = _view(night, [7.0, 0.2, -0.1])
    fg, bg = scene_for_frame(night, 0, settings=settings), scene_for_frame(night, 0, with_target=False, settings=settings)
    render = render_view(cam, fg, settings=settings)
    assert render.target_px > 400 and not (render.image[render.target_mask] > settings.ambient + 1e-6).any()  # all unlit
    photo, sky = quantise(render.image), quantise(render_view(cam, bg, settings=settings).image)
    plain = detect_target(photo, sky, DetectionSettings())
    assert plain.threshold == 0.0 and plain.area_px >= 0.95 * render.target_px  # the old behaviour, Otsu at 0
    assert detect_target(photo, sky, DetectionSettings(min_level=unlit_level(None, settings))).area_px == 0
    noisy = PhysicalCamera(noise_sigma=0.01, noise_poisson_a=0.002, exposure_ev=1.0, ambient_light=0.02)
    floor = DetectionSettings(min_level=unlit_level(noisy, settings))
    dfg, dbg = scene_for_frame(day, 0, settings=settings), scene_for_frame(day, 0, with_target=False, settings=settings)
    for inst, scenes, lit_share in ((night, (fg, bg), 0.0), (day, (dfg, dbg), 0.8)):
        shot = emulate_shots([cam], *scenes, noisy, settings=settings, seed=3)[0]
        det = detect_target(quantise(shot.photo), quantise(shot.background), floor)
        lit = shot.target_mask & (render_view(cam, scenes[0], settings=settings).image > settings.ambient + 1e-6)
        assert det.area_px <= lit.sum() + 0.02 * render.target_px and det.area_px >= lit_share * lit.sum(), inst.name
        assert np.count_nonzero(det.mask & ~lit) <= 0.05 * max(det.area_px, 1)


@pytest.fixture(scope="module")
def validated(tmp_path_factory) -> tuple[Path, dict]:
    """``camplace run`` on the night and the day instance, then one ``camplace validate`` of both
    (systems 1 and 2) with a random night system (system 3), emulated perfect photographs."""
    work = tmp_path_factory.mktemp("night")
    for name, light_x in (("night", -100.0), ("day", 100.0)):
        (work / f"{name}.toml").write_text(INSTANCE.format(name=name, light_x=light_x))
        _cli("run", f"{name}.toml", "-o", name, "--candidates", "30", "--points", "600", "--no-cache", cwd=work)
    _cli("validate", "night", "day", "--random-systems", "1", "-o", "val", cwd=work)
    return work, json.loads((work / "val" / "validation.json").read_text())


def test_validate_counts_no_unlit_point_as_seen(validated) -> None:
    """The photo figure never beats the ray cast of the same points at the same poses: 0 on the
    night side (about 0.5 before the fix), and on the day side it still finds most of what the ray cast sees."""
    work, rep = validated
    systems = {s["system"]: s for s in rep["installed"]["systems"]}
    assert set(systems) == {1, 2, 3}
    for n, s in systems.items():
        assert s["photo"]["mean"] <= s["objective_frame"]["mean"] + 0.02, (n, s["photo"], s["objective_frame"])
    for n in (1, 3):  # night
        assert systems[n]["objective_frame"]["mean"] == 0.0 and systems[n]["photo"]["mean"] == 0.0
    day = systems[2]
    assert day["objective_frame"]["mean"] > 0.3 and day["photo"]["mean"] >= 0.7 * day["objective_frame"]["mean"]
    assert rep["settings"]["detection_floors"][0]["photo"] == pytest.approx(unlit_level(None, RenderSettings()))


def test_validate_detects_the_lit_target_only(validated) -> None:
    """Per camera: nothing is detected in a night view, the lit face is in a day view, and a perfect
    camera still agrees with its own prediction (like for like)."""
    work, rep = validated
    assert len(rep["cameras"]) == 6
    for c in rep["cameras"]:
        assert c["target_px"] > 300, c
        if c["system"] == 2:
            assert c["detected_px"] >= 0.5 * c["target_px"] and c["iou"] == 1.0, c
        else:
            assert c["detected_px"] == 0 and c["predicted_px"] == 0, c


def test_report_boxes_only_the_lit_target(validated) -> None:
    """The report's rendered views box what validate detects: nothing on the night side (the plain
    detection boxed the dark outline), the lit face on the day side."""
    from camplace.instance import load_instance
    from camplace.report.build import _renders_html
    from camplace.validation.workflow import render_run

    work, _ = validated
    for name, boxed in (("night", False), ("day", True)):
        render_run(work / name)
        rjson, inst = work / name / "render" / "render.json", load_instance(work / name / "instance.toml")
        html = _renders_html(rjson, inst)
        assert html.count("no target detected") == (0 if boxed else 2), name
        assert ("lit pixels only" in html) and html.count("box x=") == (2 if boxed else 0)
        if not boxed:
            assert _renders_html(rjson).count("box x=") == 2  # without the floor: the dark outline
