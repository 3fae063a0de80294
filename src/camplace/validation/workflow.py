"""The validation stage end to end: render a run, photograph it (real or emulated), compare, export.

These functions back the ``render``, ``validate``, ``import-cameras`` and ``export`` verbs; each
writes its outputs atomically and returns what it wrote.

File names follow the thesis's convention ``e{experiment}.{system}.camera_{n}`` (section 6.1):
experiment = the instance name unless given, system = 1 unless given (systems and cameras count
from 1, as in the thesis), and ``.frame_{f}`` is appended when the instance has more than one frame.
"""

from __future__ import annotations

import csv
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from camplace._io import staged_folder, write_json_atomic, write_text_atomic
from camplace.errors import CamplaceError
from camplace.geometry import box_mesh  # noqa: F401  (also re-exported)
from camplace.validation.cameras import CameraSet, CameraView, camera_stem

if TYPE_CHECKING:
    from camplace.instance.lab import TransformConfig

log = logging.getLogger(__name__)

__all__ = [
    "load_run",
    "parse_frames",
    "frame_stem",
    "render_folder",
    "render_run",
    "read_table_file",
    "Photo",
    "read_manifest",
    "find_photos",
    "parse_target",
    "validate_cameras",
    "validate_runs",
    "export_run",
]

PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
#: the sub-folder of a validation folder that holds the emulated photographs and their manifest.csv
PHOTOS_FOLDER = "photos"

#: what the photographs' detections are compared with (``settings.prediction`` of validation.json)
PREDICTION = ("Algorithm 3 on the nominal camera's render as an 8-bit photo, against its background render when the photo "
              "has a background photograph (like for like); second figure (*_target): the ray-cast target mask alone")


# --------------------------------------------------------------------------------------------------
# runs and config tables


def load_run(outdir: str | Path):
    """The instance and solution of a ``camplace run`` output folder.

    Returns
    -------
    instance : camplace.instance.Instance
    solution : camplace.solution.Solution
    """
    from camplace.runfolder import RunFolder

    run = RunFolder(outdir)
    solution, instance = run.solution, run.instance
    run.require_cameras()
    return instance, solution


def parse_frames(spec: str, n_frames: int) -> list[int]:
    """``"all"`` or a comma list such as ``"0,3"`` -> frame indices (checked against ``n_frames``)."""
    if spec.strip().lower() == "all":
        return list(range(n_frames))
    try:
        frames = [int(x) for x in spec.split(",") if x.strip()]
    except ValueError:
        raise CamplaceError(f"--frames: use 'all' or frame numbers such as 0,3; got {spec!r}") from None
    if not frames:
        raise CamplaceError("--frames: no frame given (use 'all' or numbers such as 0,3)")
    for f in frames:
        if not 0 <= f < n_frames:
            raise CamplaceError(f"--frames: frame {f} does not exist (the instance has frames 0..{n_frames - 1})")
    return sorted(set(frames))


def frame_stem(experiment: str, system: int, camera: int, frame: int, n_frames: int) -> str:
    """``e{experiment}.{system}.camera_{n}`` plus ``.frame_{f}`` when the instance has several frames."""
    stem = camera_stem(experiment, system, camera)
    return f"{stem}.frame_{frame}" if n_frames > 1 else stem


def read_table_file(path: str | Path, table: str) -> dict[str, Any]:
    """A config table from a TOML or JSON file: the file's ``[table]`` if it has one, else the whole file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read ({exc.strerror}; check the path)") from None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CamplaceError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    else:
        data = _toml_loads(text, path)
    if not isinstance(data, dict):
        raise CamplaceError(f"{path}: must hold a table of settings")
    inner = data.get(table)
    return inner if isinstance(inner, dict) else data


def _toml_loads(text: str, path: Path) -> dict[str, Any]:
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CamplaceError(f"{path}: not valid TOML ({exc})") from None


# --------------------------------------------------------------------------------------------------
# render


def _frame_emitters(instance, frame: int):
    return getattr(instance.frames[frame], "emitters", None)


def render_folder(outdir: str | Path, phase: int | None = None) -> Path:
    """``render``'s default output folder: ``OUTDIR/render``, or ``OUTDIR/render-phaseP`` for a phase."""
    return Path(outdir) / ("render" if phase is None else f"render-phase{phase}")


def render_run(
    outdir: str | Path,
    *,
    frames: str | None = "all",
    bit_depth: int = 8,
    experiment: str | None = None,
    system: int = 1,
    out: str | Path | None = None,
    settings=None,
    emitters: Any = None,
    workers: int | None = None,
    phase: int | None = None,
) -> dict[str, Any]:
    """Render every chosen camera of a run in the chosen frames.

    Writes into ``out`` (default ``OUTDIR/render``), per camera n (1-based) and frame f:
    ``e{exp}.{sys}.camera_{n}[.frame_{f}].png`` (with the target), ``....background.png`` (occluders
    only), ``....mask.png`` (predicted target mask, 0/255), and ``render.json`` listing them.

    Parameters
    ----------
    outdir : path
        A ``camplace run`` output folder.
    frames : str
        "all" or a comma list of frame indices.
    bit_depth : {8, 16}
    experiment : str or None
        Default: the instance name.
    system : int
        System number in the file names.
    out : path or None
        Default :func:`render_folder` (``OUTDIR/render``, ``OUTDIR/render-phaseP`` with ``phase``).
    settings : RenderSettings or None
    emitters : optional
        Extra emitters for every frame (GlowEmitters); the frames' own emitters are always drawn.
    workers : int or None
    phase : int or None
        Render the moving agents' poses of this phase of ``OUTDIR/plan.json`` instead of the run's
        cameras (frames default to the phase's; see :mod:`camplace.plan`).

    Returns
    -------
    dict
        The content of ``render.json``.
    """
    from camplace.validation.render import RenderSettings, add_glow, as_glow, render_view, scene_for_frame, write_mask_png, write_png

    instance, solution = load_run(outdir)
    if phase is not None:
        from camplace.plan.io import phase_solution

        solution, phase_frames = phase_solution(outdir, solution, phase)
        frames = ",".join(str(f) for f in phase_frames) if frames is None else frames
    frames = "all" if frames is None else frames
    settings = settings or RenderSettings()
    exp = experiment or instance.name
    out = Path(out) if out is not None else render_folder(outdir, phase)
    with staged_folder(out) as work:  # moved into out at the end: an interrupted render leaves out as it was
        n_frames = len(instance.frames)
        chosen = parse_frames(frames, n_frames)
        cams = CameraSet.from_solution(solution, experiment=exp, system=system).cameras
        records = []
        for f in chosen:
            fg_scene = scene_for_frame(instance, f, with_target=True, settings=settings)
            bg_scene = scene_for_frame(instance, f, with_target=False, settings=settings)
            own = _frame_emitters(instance, f)
            for n, cam in enumerate(cams, start=1):
                stem = frame_stem(exp, system, n, f, n_frames)
                t0 = time.perf_counter()
                fg = render_view(cam, fg_scene, settings=settings, emitters=own, workers=workers)
                if emitters is not None:
                    add_glow(fg, as_glow(emitters, settings), settings)
                bg = render_view(cam, bg_scene, settings=settings, workers=workers)
                dt = time.perf_counter() - t0
                write_png(work / f"{stem}.png", fg.image, bit_depth)
                write_png(work / f"{stem}.background.png", bg.image, bit_depth)
                write_mask_png(work / f"{stem}.mask.png", fg.target_mask)
                records.append(
                    {
                        "camera": n,
                        "candidate": solution.cameras[n - 1].get("candidate"),
                        "frame": f,
                        "image": f"{stem}.png",
                        "background": f"{stem}.background.png",
                        "mask": f"{stem}.mask.png",
                        "target_px": fg.target_px,
                        # light the event adds to the view: target + emitters, over the background
                        "event_intensity": float(np.clip(fg.image - bg.image, 0.0, None).sum(dtype=np.float64)),
                        "width": cam.width,
                        "height": cam.height,
                        "render_s": dt,
                        **({"model": cam.model} if cam.model else {}),
                    }
                )
                log.info("rendered %s (%d target px, %.3f s for both images)", stem, fg.target_px, dt)
        manifest = {
            "experiment": exp,
            "system": system,
            "instance": instance.name,
            "bit_depth": bit_depth,
            "frames": chosen,
            "settings": settings.__dict__,
            "images": records,
            "warnings": _render_warnings(records),
        }
        for note in manifest["warnings"]:
            log.warning("%s", note)
        write_json_atomic(work / "render.json", manifest)
        # rendered light curves: per camera (0-based, as in the run's light_curves.csv) and frame
        lines = ["camera,frame,rendered_intensity,target_px,candidate"]
        for r in sorted(records, key=lambda r: (r["camera"], r["frame"])):
            lines.append(f"{r['camera'] - 1},{r['frame']},{r['event_intensity']!r},{int(r['target_px'])},{r['candidate']}")
        write_text_atomic(work / "light_curves.csv", "\n".join(lines) + "\n")
    return manifest


def _render_warnings(records: list[dict]) -> list[str]:
    """A warning when the target covers fewer than ``SMALL_TARGET_PX`` pixels in every rendered view."""
    from camplace.visibility.footprint import SMALL_TARGET_PX

    if not records or max(int(r["target_px"]) for r in records) >= SMALL_TARGET_PX:
        return []
    return [f"the target covers at most {max(int(r['target_px']) for r in records)} px in every rendered view (fewer than "
            f"{SMALL_TARGET_PX:g} px: Algorithm 3 cannot detect it); check the mesh scale and the camera (see the run's warnings)"]


# --------------------------------------------------------------------------------------------------
# photographs


@dataclass(frozen=True)
class Photo:
    """A photograph of one camera and, optionally, its background photograph (paths)."""

    camera: str
    photo: Path
    background: Path | None = None


def read_manifest(path: str | Path, photos_dir: str | Path | None = None) -> dict[str, Photo]:
    """Read a manifest CSV with header ``camera,photo,background`` (background optional/empty).

    Relative photo paths are resolved against ``photos_dir`` (default: the manifest's folder).

    Returns
    -------
    dict of camera name -> Photo
    """
    path = Path(path)
    base = Path(photos_dir) if photos_dir is not None else path.parent
    try:
        text = path.read_text()
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read the manifest ({exc.strerror}; check the path)") from None
    reader = csv.DictReader(text.splitlines())
    cols = [c.strip() for c in (reader.fieldnames or [])]
    if "camera" not in cols or "photo" not in cols:
        raise CamplaceError(f"{path}: the header must be 'camera,photo,background' (background optional), got {','.join(cols) or 'nothing'}")
    out: dict[str, Photo] = {}
    for i, row in enumerate(reader, start=2):
        row = {(k or "").strip(): (v or "").strip() for k, v in row.items()}
        cam, photo = row.get("camera", ""), row.get("photo", "")
        if not cam or not photo:
            raise CamplaceError(f"{path}:{i}: every row needs a camera name and a photo file")
        if cam in out:
            raise CamplaceError(f"{path}:{i}: camera {cam!r} is listed twice")
        p = Path(photo) if Path(photo).is_absolute() else base / photo
        if not p.exists():
            raise CamplaceError(f"{path}:{i}: photo {photo} not found in {base}")
        bg = row.get("background", "")
        b = None
        if bg:
            b = Path(bg) if Path(bg).is_absolute() else base / bg
            if not b.exists():
                raise CamplaceError(f"{path}:{i}: background {bg} not found in {base}")
        out[cam] = Photo(cam, p, b)
    if not out:
        raise CamplaceError(f"{path}: the manifest lists no photos")
    return out


def find_photos(cameras: Sequence[CameraView], photos_dir: str | Path, manifest: str | Path | None = None) -> dict[str, Photo]:
    """Photos of the cameras: from the manifest (default ``photos_dir/manifest.csv`` when present),
    else by each camera's ``image`` file name or ``{name}.png|.jpg|...`` in ``photos_dir``.

    Cameras without a photo are left out (and logged); an error if none has one, or if the
    manifest names a camera that does not exist.
    """
    photos_dir = Path(photos_dir)
    if not photos_dir.is_dir():
        raise CamplaceError(f"--photos: {photos_dir} is not a folder")
    names = {c.name for c in cameras}
    if manifest is None and (photos_dir / "manifest.csv").exists():
        manifest = photos_dir / "manifest.csv"
    if manifest is not None:
        found = read_manifest(manifest, photos_dir)
        unknown = sorted(set(found) - names)
        if unknown:
            raise CamplaceError(f"{manifest}: camera {unknown[0]!r} is not one of the cameras ({', '.join(sorted(names)[:6])}{', ...' if len(names) > 6 else ''})")
    else:
        found = {}
        for c in cameras:
            cands = ([c.image] if c.image else []) + [c.name + ext for ext in PHOTO_EXTENSIONS]
            for cand in cands:
                if (photos_dir / cand).exists():
                    bg = None
                    stem = Path(cand).stem
                    for ext in PHOTO_EXTENSIONS:
                        if (photos_dir / f"{stem}.background{ext}").exists():
                            bg = photos_dir / f"{stem}.background{ext}"
                            break
                    found[c.name] = Photo(c.name, photos_dir / cand, bg)
                    break
    missing = [c.name for c in cameras if c.name not in found]
    if missing:
        log.warning("%d camera(s) have no photo: %s", len(missing), ", ".join(missing[:5]))
    if not found:
        raise CamplaceError(f"--photos: no photo in {photos_dir} matches a camera (name photos '{cameras[0].name}.png' or write a manifest.csv with camera,photo,background)")
    return found


# --------------------------------------------------------------------------------------------------
# targets


def parse_target(spec: str) -> tuple[np.ndarray, np.ndarray]:
    """``box:x0,y0,z0,x1,y1,z1`` (an axis-aligned box, metres) or a mesh file -> (vertices (n, 3), faces (m, 3))."""
    if spec.startswith("box:"):
        try:
            vals = [float(x) for x in spec[4:].split(",")]
        except ValueError:
            raise CamplaceError(f"--target: a box is box:x0,y0,z0,x1,y1,z1 (6 numbers), got {spec!r}") from None
        if len(vals) != 6:
            raise CamplaceError(f"--target: a box is box:x0,y0,z0,x1,y1,z1 (6 numbers), got {len(vals)}")
        lo, hi = np.minimum(vals[:3], vals[3:]), np.maximum(vals[:3], vals[3:])
        if np.any(hi <= lo):
            raise CamplaceError(f"--target: the box {spec!r} has zero thickness along an axis")
        return box_mesh(lo, hi)
    path = Path(spec)
    if not path.exists():
        raise CamplaceError(f"--target: {spec} is neither box:x0,y0,z0,x1,y1,z1 nor an existing mesh file")
    from camplace.instance.meshio import read_mesh_file

    try:
        v, f = read_mesh_file(path)
    except Exception as exc:  # trimesh raises many kinds
        raise CamplaceError(f"--target: cannot read mesh {path} ({exc})") from None
    if len(f) == 0:
        raise CamplaceError(f"--target: {path} has no triangles")
    return v, f


# --------------------------------------------------------------------------------------------------
# comparison


def _compare_one(name: str, system: int, cam: CameraView, render, background_render: np.ndarray | None,
                 photo: np.ndarray, background: np.ndarray | None, detection_settings, extra: dict,
                 *, intensity: bool = True, render_detection=None) -> tuple[dict, Any, Any]:
    """One camera's record: the photo's detection against the prediction and against the target mask.

    Parameters
    ----------
    render : RenderResult
        The nominal camera's render with the target.
    background_render : (h, w) float32 or None
        Its render without the target; used (as the photo's background is) only when ``background`` is given.
    photo, background : (h, w[, 3]) float32
        The photograph and its background photograph (or None).
    intensity : bool
        Record the render's intensities (False when the render has no light: cameras mode).
    render_detection : DetectionSettings or None
        Algorithm 3's settings on the render (default ``detection_settings``; they differ by the
        unlit floor, :func:`observable_detection`).

    Returns
    -------
    (record dict, Detection in the photo, expected Detection in the render)
    """
    from camplace.validation.compare import mask_metrics, target_metrics
    from camplace.validation.detect import detect_target, expected_detection

    if photo.shape[:2] != (cam.height, cam.width):
        raise CamplaceError(f"camera {name}: photo is {photo.shape[1]}x{photo.shape[0]} but the camera is {cam.width}x{cam.height} (check the calibration or the manifest)")
    det = detect_target(photo, background, detection_settings)
    expected = expected_detection(render.image, background_render if background is not None else None,
                                  detection_settings if render_detection is None else render_detection)
    rec: dict[str, Any] = {"name": name, "system": system, "width": cam.width, "height": cam.height}
    rec.update(mask_metrics(expected.mask, det.mask))
    rec.update(target_metrics(render.target_mask, det.mask, expected.mask))
    pred_i = expected.mean_intensity if intensity and expected.area_px else None
    target_i = None
    if intensity and render.target_mask.any():
        target_i = float(np.clip(render.image[render.target_mask], 0.0, 1.0).mean())
    rec["predicted_intensity"] = pred_i
    rec["target_intensity"] = target_i
    rec["detected_intensity"] = det.mean_intensity if det.area_px else None
    rec["intensity_difference"] = None if pred_i is None or not det.area_px else det.mean_intensity - pred_i
    rec["bbox_xywh"] = None if det.bbox_xywh is None else list(det.bbox_xywh)
    rec["threshold"] = det.threshold
    rec["n_contours"] = det.n_contours
    rec.update(extra)
    return rec, det, expected


def observable_detection(detection, instance, physical, settings) -> tuple[Any, Any]:
    """Algorithm 3's settings on a system's photographs and on its renders, restricted to what its
    instance counts as observable.

    With ``[quality] require_light`` and emulated photographs, each gets the floor of an unlit
    surface (:func:`camplace.validation.physical.unlit_level`): the photographs the emulated
    camera's, the renders a perfect camera's, so the night side, seen by the ambient term alone, is
    detected in neither. Real photographs (``physical`` None) keep ``detection``: their unlit level
    is unknown (set ``--threshold`` for them).

    Parameters
    ----------
    detection : DetectionSettings
    instance : camplace.instance.Instance
    physical : PhysicalCamera or None
        The emulated camera; None for real photographs.
    settings : RenderSettings

    Returns
    -------
    (DetectionSettings, DetectionSettings)
        For the photographs, for the renders.
    """
    from camplace.validation.physical import unlit_level

    if physical is None or not instance.quality.require_light:
        return detection, detection
    return detection.with_floor(unlit_level(physical, settings)), detection.with_floor(unlit_level(None, settings))


def _finish_report(records: list[dict], out: Path, overlays: list[tuple[str, np.ndarray]], settings: dict,
                   installed: dict | None = None):
    from camplace.validation.compare import (
        ValidationReport,
        across_systems,
        agreement,
        difference_matrix,
        heatmap_image,
        kde_image,
        system_scores,
    )
    from camplace.validation.render import write_png

    figures = []
    for fname, img in overlays:
        write_png(out / fname, img)
        figures.append(fname)
    systems = system_scores(records)
    across = across_systems(systems)
    heat: dict[str, Any] = {"labels": [r["name"] for r in records]}
    cov_p = [r["predicted_px"] / (r["width"] * r["height"]) for r in records]
    cov_d = [r["detected_px"] / (r["width"] * r["height"]) for r in records]
    heat["coverage_difference"] = difference_matrix(cov_p, cov_d).tolist()
    write_png(out / "heatmap_coverage.png", heatmap_image(np.array(heat["coverage_difference"]), "|coverage difference| (fraction of image)"))
    figures.append("heatmap_coverage.png")
    if all(r["predicted_intensity"] is not None and r["detected_intensity"] is not None for r in records):
        heat["intensity_difference"] = difference_matrix([r["predicted_intensity"] for r in records], [r["detected_intensity"] for r in records]).tolist()
        write_png(out / "heatmap_intensity.png", heatmap_image(np.array(heat["intensity_difference"]), "|mean target intensity difference|"))
        figures.append("heatmap_intensity.png")
    else:
        heat["intensity_difference"] = None
        across["notes"].append("no intensity heatmap: a predicted intensity needs a rendered scene, or a camera detected nothing")
    if len(systems) >= 2:
        write_png(out / "kde_scores.png", kde_image([s["normalised_predicted"] for s in systems], [s["normalised_photo"] for s in systems]))
        figures.append("kde_scores.png")
    report = ValidationReport(cameras=records, systems=systems, across=across, heatmaps=heat, settings=settings, figures=figures,
                              agreement=agreement(records), installed=installed or {})
    report.save(out)
    return report


def validate_cameras(
    cameras: CameraSet,
    target: tuple[np.ndarray, np.ndarray],
    photos_dir: str | Path,
    out: str | Path,
    *,
    manifest: str | Path | None = None,
    detection=None,
    target_spec: str = "",
    workers: int | None = None,
) -> Any:
    """Compare photographs of a target with the masks predicted from calibrated cameras (no instance).

    The target mask of each camera is the target mesh ray cast alone (no other geometry, no light);
    the prediction is Algorithm 3 run on that render (the target on black; against a black
    background render when the photo has a background photograph).
    Writes ``validation.json``, ``overlay.{camera}.png`` figures and ``scene3d.html`` (every
    camera of ``cameras`` around the target, :mod:`camplace.validation.camera_scene`) into ``out``.

    Returns
    -------
    ValidationReport
    """
    from camplace.validation.compare import overlay_image
    from camplace.validation.detect import DetectionSettings
    from camplace.validation.render import RenderSettings, read_image, render_view, target_scene

    detection = detection or DetectionSettings()
    out = Path(out)
    photos = find_photos(cameras.cameras, photos_dir, manifest)
    scene = target_scene(*target)
    records, overlays = [], []
    for cam in cameras.cameras:
        if cam.name not in photos:
            continue
        ph = photos[cam.name]
        pred = render_view(cam, scene, workers=workers)
        photo = read_image(ph.photo)
        bg = read_image(ph.background) if ph.background is not None else None
        empty = np.full(pred.image.shape, RenderSettings().background, dtype=np.float32)
        rec, det, expected = _compare_one(cam.name, 1, cam, pred, empty, photo, bg, detection,
                                          {"photo": str(ph.photo), "background": None if ph.background is None else str(ph.background)},
                                          intensity=False)
        records.append(rec)
        overlays.append((f"overlay.{cam.name}.png", overlay_image(photo, expected.mask, det.mask, det.bbox_xywh, cam.name, target=pred.target_mask)))
    settings = {
        "mode": "cameras",
        "prediction": PREDICTION,
        "cameras": cameras.source,
        "target": target_spec,
        "photos": str(photos_dir),
        "manifest": None if manifest is None else str(manifest),
        "detection": detection.to_dict(),
    }
    with staged_folder(out) as work:  # moved into out at the end (see validate_runs)
        report = _finish_report(records, work, overlays, settings)
        _write_cameras_scene(work, out, cameras.cameras, target, title=Path(cameras.source).name or "cameras", target_name=_target_label(target_spec),
                             meta={"mode": "cameras", "cameras_file": cameras.source, "target": target_spec,
                                   "photographed": [r["name"] for r in records]})
    return report


def _target_label(spec: str) -> str:
    """A short name for ``--target``: "box" or the mesh file's name."""
    return "box" if spec.startswith("box:") else (Path(spec).name or "target")


def _write_cameras_scene(work: Path, final: Path, cameras, target, **scene_options) -> None:
    """``work/scene3d.html`` (skipped with a warning when plotly is missing, and then a stale one
    of an earlier validation in ``final``, the folder ``work`` is moved into, is removed)."""
    from camplace.validation.camera_scene import SCENE3D_FILE, cameras_scene, write_scene3d

    if write_scene3d(work, cameras_scene(cameras, target, **scene_options)) is None:
        (final / SCENE3D_FILE).unlink(missing_ok=True)


def _run_physical(instance):
    """The physical camera of a run: its instance's parsed ``[physical]`` table, else a perfect camera."""
    from camplace.instance.lab import PhysicalCamera

    if instance.physical is None:
        log.warning("no photos and no [physical] table: emulating a perfect camera (photos equal the renders)")
        return PhysicalCamera()
    return instance.physical


def _random_systems(outdir: Path, instance, solution, n: int, rng: np.random.Generator, experiment: str, first_system: int) -> list[list[CameraView]]:
    from camplace.runfolder import RunFolder

    cands = RunFolder(outdir).candidates
    k = len(solution.cameras)
    if len(cands) < k:
        raise CamplaceError(f"--random-systems: {outdir / 'candidates.csv'} has fewer than k = {k} candidates")
    K = np.asarray(solution.cameras[0]["K"], dtype=np.float64)
    w, h = int(solution.cameras[0]["width"]), int(solution.cameras[0]["height"])
    team = getattr(instance, "team", None) is not None
    models = cands.models()

    def view(name: str, i: int) -> CameraView:
        if not team:
            return CameraView(name, cands.positions[i], cands.rotations[i], K, w, h)
        m = instance.cameras[int(models[i])]  # a team's candidate: its model's intrinsics
        return CameraView(name, cands.positions[i], cands.rotations[i], m.K(), m.width_px, m.height_px, model=m.name)

    systems = []
    for s in range(n):
        idx = rng.choice(len(cands), size=k, replace=False)
        systems.append([view(camera_stem(experiment, first_system + s, j + 1), i) for j, i in enumerate(idx)])
    return systems


def validate_runs(
    outdirs: Sequence[str | Path],
    out: str | Path,
    *,
    photos_dir: str | Path | None = None,
    manifest: str | Path | None = None,
    physical=None,
    frame: int = 0,
    seed: int = 0,
    random_systems: int = 0,
    experiment: str | None = None,
    detection=None,
    settings=None,
    workers: int | None = None,
    installations: int = 1,
) -> Any:
    """Validate one or more runs: each run's chosen cameras form a system (numbered 1, 2, ... in order).

    Photographs come from ``photos_dir`` (manifest or file names ``e{exp}.{sys}.camera_{n}.png``)
    or, when it is None, are emulated with ``physical`` (default: the first run's ``[physical]``
    table, else a perfect camera) and written to ``out/photos`` with a ``manifest.csv``.
    ``random_systems`` adds that many systems of k candidates drawn at random (seeded) from the
    first run's ``candidates.csv``, as a baseline for the across-system statistics.

    Each photo's detection (Algorithm 3) is compared with the same detection run on the nominal
    camera's render (against its background render when the photo has a background): a perfect
    camera scores IoU 1. The ray-cast target mask alone is the second figure (``*_target`` fields).

    With emulated photographs every system is also installed ``installations`` times (the first
    installation is the one photographed for the per-camera comparison) and scored per installation
    by its run's objective at the installed poses and by the photo figure
    (:mod:`camplace.validation.installed`; ``validation.json`` ``installed``).

    Returns
    -------
    ValidationReport
    """
    from camplace.validation.compare import overlay_image
    from camplace.validation.detect import DetectionSettings
    from camplace.validation.installed import InstalledSystems
    from camplace.validation.physical import emulate_shots
    from camplace.validation.render import RenderSettings, quantise, read_image, render_view, scene_for_frame, write_png

    if not outdirs:
        raise CamplaceError("validate: give at least one OUTDIR of 'camplace run' (or --cameras with --target)")
    detection = detection or DetectionSettings()
    settings = settings or RenderSettings()
    out = Path(out)
    if int(installations) < 1:
        raise CamplaceError(f"--installations: must be >= 1, got {installations}")
    sys_rng, shot_rng = np.random.default_rng(seed).spawn(2)
    runs = [load_run(d) for d in outdirs]
    instance0 = runs[0][0]
    exp = experiment or instance0.name
    systems: list[tuple[Any, list[CameraView]]] = []
    for s, (inst, sol) in enumerate(runs, start=1):
        if not 0 <= frame < len(inst.frames):
            raise CamplaceError(f"--frame: frame {frame} does not exist in {outdirs[s - 1]} (frames 0..{len(inst.frames) - 1})")
        systems.append((inst, list(CameraSet.from_solution(sol, experiment=exp, system=s).cameras)))
    if random_systems:
        for cams in _random_systems(Path(outdirs[0]), instance0, runs[0][1], random_systems, sys_rng, exp, len(runs) + 1):
            systems.append((instance0, cams))
    all_cams = [c for _, cams in systems for c in cams]
    photos = None
    if photos_dir is not None:
        photos = find_photos(all_cams, photos_dir, manifest)
    else:
        if physical is None:
            physical = _run_physical(instance0)
    inst_plan = None if photos is not None else InstalledSystems.plan(outdirs, runs, systems, physical, seed, installations, frame)
    # Algorithm 3 on each system's photos and renders, restricted to what its instance can observe
    detections = [observable_detection(detection, inst, None if photos is not None else physical, settings) for inst, _ in systems]
    # photographs and figures go to a temporary folder, moved into out at the end: an interrupted
    # validation leaves out as it was
    with staged_folder(out) as work:
        scenes: dict[int, tuple[Any, Any]] = {}
        records, overlays, manifest_rows = [], [], []
        for s, (inst, cams) in enumerate(systems, start=1):
            key = id(inst)
            if key not in scenes:
                scenes[key] = (
                    scene_for_frame(inst, frame, with_target=True, settings=settings),
                    scene_for_frame(inst, frame, with_target=False, settings=settings),
                )
            fg_scene, bg_scene = scenes[key]
            emit = _frame_emitters(inst, frame)
            for ci, cam in enumerate(cams):
                pred = render_view(cam, fg_scene, settings=settings, emitters=emit, workers=workers)
                extra: dict[str, Any] = {}
                if photos is not None:
                    if cam.name not in photos:
                        continue
                    ph = photos[cam.name]
                    photo = read_image(ph.photo)
                    bg = read_image(ph.background) if ph.background is not None else None
                    extra = {"photo": str(ph.photo), "background": None if ph.background is None else str(ph.background)}
                else:
                    shot = emulate_shots([cam], fg_scene, bg_scene, physical, settings=settings, emitters=emit, seed=shot_rng, workers=workers,
                                         installed=[inst_plan.installed[s - 1][0][ci]])[0]
                    photo, bg = quantise(shot.photo, 8), quantise(shot.background, 8)
                    pdir = out / PHOTOS_FOLDER  # where they are once the block succeeds
                    write_png(work / PHOTOS_FOLDER / f"{cam.name}.png", photo)
                    write_png(work / PHOTOS_FOLDER / f"{cam.name}.background.png", bg)
                    manifest_rows.append(f"{cam.name},{cam.name}.png,{cam.name}.background.png")
                    dR = cam.rotation.T @ shot.actual.rotation
                    extra = {
                        "photo": str(pdir / f"{cam.name}.png"),
                        "background": str(pdir / f"{cam.name}.background.png"),
                        "pose_error_m": float(np.linalg.norm(shot.actual.position - cam.position)),
                        "pose_error_deg": float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1.0, 1.0)))),
                    }
                bg_render = render_view(cam, bg_scene, settings=settings, workers=workers).image if bg is not None else None
                photo_det, render_det = detections[s - 1]
                if cam.model:  # a team's camera: its model
                    extra = {**extra, "model": cam.model}
                rec, det, expected = _compare_one(cam.name, s, cam, pred, bg_render, photo, bg, photo_det, extra,
                                                  render_detection=render_det)
                if inst_plan is not None:
                    inst_plan.record_photo(s - 1, 0, ci, shot, det.mask)
                records.append(rec)
                overlays.append((f"overlay.{cam.name}.png", overlay_image(photo, expected.mask, det.mask, det.bbox_xywh, cam.name, target=pred.target_mask)))
        if inst_plan is not None:
            _photograph_installations(inst_plan, systems, scenes, physical, frame, settings=settings,
                                      detections=[d[0] for d in detections], rng=shot_rng, workers=workers)
        if manifest_rows:
            write_text_atomic(work / PHOTOS_FOLDER / "manifest.csv", "camera,photo,background\n" + "\n".join(manifest_rows) + "\n")
        if not records:
            raise CamplaceError("validate: no camera had a photo to compare")
        report_settings = {
            "mode": "runs",
            "prediction": PREDICTION,
            "runs": [str(d) for d in outdirs],
            "experiment": exp,
            "frame": frame,
            "seed": seed,
            "random_systems": random_systems,
            "photos": None if photos_dir is None else str(photos_dir),
            "manifest": None if manifest is None else str(manifest),
            "physical": None if photos is not None else physical.to_dict(),
            "detection": detection.to_dict(),
            "detection_floors": [None if p.min_level == detection.min_level and r.min_level == detection.min_level
                                 else {"photo": p.min_level, "render": r.min_level} for p, r in detections],
            "render": settings.__dict__,
            "installations": int(installations) if photos is None else None,
        }
        installed = inst_plan.finish(systems) if inst_plan is not None else {
            "available": False, "note": "real photographs: the poses they were taken from are unknown (emulate them with --physical)"}
        report = _finish_report(records, work, overlays, report_settings, installed=installed)
        inst1, cams1 = systems[0]
        em = _frame_emitters(inst1, frame)
        _write_cameras_scene(work, out, cams1, inst1.target_world(frame), title=f"{exp}, frame {frame}", target_name=inst1.target.name,
                             occluders=inst1.occluders_world(frame), emitters=None if em is None else em.positions_m,
                             other_systems=[(f"system {s}", cams) for s, (_, cams) in enumerate(systems[1:], start=2)],
                             seed=seed, meta={"mode": "runs", "runs": [str(d) for d in outdirs], "frame": frame})
        return report


def _photograph_installations(plan, systems, scenes, physical, frame: int, *, settings, detections, rng, workers) -> None:
    """Photograph installations 2..N of every system (not written to disk) and record what each
    photo sees (:meth:`camplace.validation.installed.InstalledSystems.record_photo`); ``detections``:
    Algorithm 3's settings per system (:func:`observable_detection`)."""
    from camplace.validation.detect import detect_target
    from camplace.validation.physical import emulate_shots
    from camplace.validation.render import quantise

    for t in range(1, plan.installations):
        for s, (inst, cams) in enumerate(systems):
            fg_scene, bg_scene = scenes[id(inst)]
            emit = _frame_emitters(inst, frame)
            for ci, cam in enumerate(cams):
                shot = emulate_shots([cam], fg_scene, bg_scene, physical, settings=settings, emitters=emit, seed=rng, workers=workers,
                                     installed=[plan.installed[s][t][ci]])[0]
                det = detect_target(quantise(shot.photo, 8), quantise(shot.background, 8), detections[s])
                plan.record_photo(s, t, ci, shot, det.mask)
        log.info("photographed installation %d of %d", t + 1, plan.installations)


# --------------------------------------------------------------------------------------------------
# export


def export_run(outdir: str | Path, *, frame: str = "physical", transform: dict[str, Any] | TransformConfig | None = None,
               transform_source: str = "", out: str | Path | None = None) -> tuple[Path, Path]:
    """Write the chosen cameras' placement in the simulation or physical frame.

    Parameters
    ----------
    outdir : path
        A ``camplace run`` output folder.
    frame : {"physical", "simulation"}
    transform : dict, TransformConfig or None
        The ``[transform]`` table (physical frame), raw (parsed here) or parsed; default: the
        run's instance's :attr:`~camplace.instance.Instance.transform`.
    transform_source : str
        Where ``transform`` came from (for error messages).
    out : path or None
        Output folder (default ``outdir``).

    Returns
    -------
    (csv path, json path) of ``placement.{frame}.csv`` / ``.json``
    """
    from camplace.runfolder import RunFolder
    from camplace.instance.lab import TransformConfig
    from camplace.validation.transform import build_transform, parse_transform, placement_rows, write_placement

    outdir = Path(outdir)
    run = RunFolder(outdir)
    solution = run.solution
    if frame == "simulation":
        tr = build_transform(TransformConfig())
    elif frame == "physical":
        if transform is None:
            transform = run.instance.transform
            if transform is None:
                raise CamplaceError(f"{outdir / 'instance.toml'}: no [transform] table for lab coordinates (add one, pass --transform FILE, "
                                    f"or use --frame simulation for the run's own coordinates; see docs/validation.md)")
        if not isinstance(transform, TransformConfig):
            transform = parse_transform(transform, transform_source or "[transform]")
        tr = build_transform(transform)
    else:
        raise CamplaceError(f"--frame: must be physical or simulation, got {frame!r}")
    exp = solution.instance or "camplace"
    cams = [
        {"name": camera_stem(exp, 1, n), "position": c["position"], "rotation": c["rotation"], "aim": c.get("aim")}
        for n, c in enumerate(solution.cameras, start=1)
    ]
    rows = placement_rows(cams, tr)
    return write_placement(Path(out) if out is not None else outdir, rows, tr, frame)
