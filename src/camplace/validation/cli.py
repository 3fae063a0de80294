"""Verbs of the validation stage: ``render``, ``validate``, ``import-cameras`` (``export`` is in :mod:`camplace.report.cli`).

Imports nothing heavy at module level (OpenCV and Embree load when a verb runs).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable

from camplace.errors import CamplaceError, EXIT_OK



def register(subparsers, add_run_options: Callable[[argparse.ArgumentParser], None]) -> dict[str, Callable[[argparse.Namespace], int]]:
    """Add the validation verbs to ``subparsers``; returns {verb: handler}."""
    p = subparsers.add_parser("render", help="ray-cast each chosen camera's view: image, background and target mask PNGs")
    p.add_argument("outdir", type=Path, help="output folder of 'camplace run'")
    p.add_argument("--frames", default=None, help="'all' (default; with --phase: that phase's frames) or frame numbers such as 0,3")
    p.add_argument("--16bit", dest="bit16", action="store_true", help="write 16-bit PNGs (default 8-bit)")
    p.add_argument("-o", "--out", type=Path, default=None, help="folder for the images (default OUTDIR/render)")
    p.add_argument("--experiment", default=None, help="experiment name in file names (default: the instance name)")
    p.add_argument("--system", type=int, default=1, help="system number in file names (default 1)")
    p.add_argument("--emitters", type=Path, default=None, help="CSV of extra glowing emitters: x,y,z,brightness[,radius_m]")
    p.add_argument("--workers", type=int, default=None, help="render threads (default: all cores)")
    p.add_argument("--phase", type=int, default=None, help="render the moving agents' poses of this phase of plan.json (default out: OUTDIR/render-phaseP)")

    p = subparsers.add_parser("validate", help="compare predicted target masks with (real or emulated) photographs")
    p.add_argument("outdirs", nargs="*", type=Path, help="output folders of 'camplace run' (one camera system each)")
    p.add_argument("--cameras", type=Path, default=None, help="cameras.json (from import-cameras) instead of run folders")
    p.add_argument("--target", default=None, help="with --cameras: box:x0,y0,z0,x1,y1,z1 or a mesh file")
    p.add_argument("--photos", type=Path, default=None, help="folder of photographs (default: emulate them)")
    p.add_argument("--manifest", type=Path, default=None, help="CSV camera,photo,background (default PHOTOS/manifest.csv or by name)")
    p.add_argument("--physical", type=Path, default=None, help="TOML/JSON with the emulated camera's [physical] settings")
    p.add_argument("--frame", type=int, default=0, help="frame the photos show (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the emulation and random systems (default 0)")
    p.add_argument("--random-systems", type=int, default=0, dest="random_systems", help="add N random k-camera systems from candidates.csv as a baseline")
    p.add_argument("--installations", type=int, default=1, help="emulated photos: install every system N times (the [physical] pose error) and "
                   "score each installation by the run's objective and by the photographs (default 1)")
    p.add_argument("--experiment", default=None, help="experiment name in camera names (default: the instance name)")
    p.add_argument("--threshold", default="otsu", help="otsu (default), triangle (better for background-subtracted or flat-shaded images), or a fixed level 0..255")
    p.add_argument("--morph-px", type=int, default=5, dest="morph_px", help="morphology kernel diameter, pixels (default 5; 0 = none)")
    p.add_argument("--largest-component", action="store_true", dest="largest", help="keep only the largest detected blob")
    p.add_argument("--workers", type=int, default=None, help="render threads (default: all cores)")
    p.add_argument("-o", "--out", type=Path, default=None,
                   help="folder for validation.json and figures (default: the first run folder's validation/; required with --cameras)")

    p = subparsers.add_parser("import-cameras", help="convert a Middlebury, COLMAP or OpenCV calibration to cameras.json")
    p.add_argument("file", type=Path, help="calibration file (COLMAP: the model folder or images.txt)")
    p.add_argument("--format", default="auto", choices=["auto", "middlebury", "colmap", "opencv"], help="input format (default: guess from the name)")
    p.add_argument("--images", type=Path, default=None, help="Middlebury: folder of the images (to read their size; default beside FILE)")
    p.add_argument("--size", default=None, help="Middlebury: image size WIDTHxHEIGHT when the images are not at hand")
    p.add_argument("-o", "--out", type=Path, required=True, help="cameras.json to write")

    return {"render": _cmd_render, "validate": _cmd_validate, "import-cameras": _cmd_import}


def _check_workers(args: argparse.Namespace) -> None:
    if args.workers is not None and args.workers < 1:
        raise CamplaceError(f"--workers: must be >= 1, got {args.workers}")


def _cmd_render(args: argparse.Namespace) -> int:
    _check_workers(args)
    from camplace.outpaths import check_out_folder
    from camplace.validation.render import GlowEmitters
    from camplace.validation.workflow import render_folder, render_run

    if args.system < 1:
        raise CamplaceError(f"--system: must be >= 1, got {args.system}")
    emitters = GlowEmitters.load_csv(args.emitters) if args.emitters is not None else None
    if args.out is None:
        args.out = render_folder(args.outdir, args.phase)
    check_out_folder(args.out, files=["render.json", "light_curves.csv"])
    manifest = render_run(
        args.outdir,
        frames=args.frames,
        bit_depth=16 if args.bit16 else 8,
        experiment=args.experiment,
        system=args.system,
        out=args.out,
        emitters=emitters,
        workers=args.workers,
        phase=args.phase,
    )
    for rec in manifest["images"]:
        print(f"  {rec['image']}: {rec['target_px']} target px ({rec['render_s']:.2f} s)")
    print(f"wrote {len(manifest['images'])} views (image, background, mask) and render.json to {args.out}")
    return EXIT_OK


def _detection_settings(args: argparse.Namespace):
    from camplace.validation.detect import DetectionSettings, parse_threshold

    if args.morph_px < 0:
        raise CamplaceError(f"--morph-px: must be >= 0, got {args.morph_px}")
    return DetectionSettings(threshold=parse_threshold(args.threshold), morph_kernel_px=args.morph_px, largest_component=args.largest)


VALIDATION_FOLDER = "validation"  # the default -o of 'camplace validate', in the first run folder


def _validate_out(args: argparse.Namespace) -> Path:
    """``validate``'s ``-o``: as given, else the first run folder's ``validation/``; checked before any work."""
    from camplace.outpaths import check_out_folder
    from camplace.validation.camera_scene import SCENE3D_FILE
    from camplace.validation.workflow import PHOTOS_FOLDER

    if args.out is None:
        if args.cameras is not None:
            raise CamplaceError("-o/--out: required with --cameras (the folder for validation.json and figures)")
        args.out = args.outdirs[0] / VALIDATION_FOLDER
    return check_out_folder(args.out, files=["validation.json", SCENE3D_FILE], folders=[PHOTOS_FOLDER])


def _cmd_validate(args: argparse.Namespace) -> int:
    from camplace.validation.workflow import read_table_file, validate_cameras, validate_runs

    _check_workers(args)
    if args.cameras is not None or args.outdirs:
        _validate_out(args)
    det = _detection_settings(args)
    if args.cameras is not None:
        from camplace.validation.cameras import CameraSet
        from camplace.validation.workflow import parse_target

        if args.outdirs:
            raise CamplaceError("validate: give run folders or --cameras, not both")
        if args.target is None:
            raise CamplaceError("--target: required with --cameras (box:x0,y0,z0,x1,y1,z1 or a mesh file)")
        if args.photos is None:
            raise CamplaceError("--photos: required with --cameras (emulating photos needs a scene: validate a run folder instead)")
        report = validate_cameras(
            CameraSet.load(args.cameras), parse_target(args.target), args.photos, args.out,
            manifest=args.manifest, detection=det, target_spec=args.target, workers=args.workers,
        )
    else:
        if not args.outdirs:
            raise CamplaceError("validate: give one or more run folders, or --cameras cameras.json --target ... --photos DIR")
        if args.random_systems < 0:
            raise CamplaceError(f"--random-systems: must be >= 0, got {args.random_systems}")
        if not 1 <= args.installations <= 4096:
            raise CamplaceError(f"--installations: must be between 1 and 4096, got {args.installations}")
        if args.installations > 1 and args.photos is not None:
            raise CamplaceError("--installations: applies to emulated photographs only (drop --photos or --installations)")
        if args.seed < 0:
            raise CamplaceError(f"--seed: must be >= 0, got {args.seed}")
        physical = None
        if args.physical is not None:
            from camplace.validation.physical import parse_physical

            physical = parse_physical(read_table_file(args.physical, "physical"), f"{args.physical}: [physical]")
        report = validate_runs(
            args.outdirs, args.out, photos_dir=args.photos, manifest=args.manifest, physical=physical,
            frame=args.frame, seed=args.seed, random_systems=args.random_systems, experiment=args.experiment,
            detection=det, workers=args.workers, installations=args.installations,
        )
    print(report.summary())
    scene = args.out / "scene3d.html"
    extra = f", {scene} (3D view)" if scene.is_file() else ""
    print(f"wrote {args.out / 'validation.json'}{extra} and {len(report.figures)} figure(s)")
    return EXIT_OK


def _cmd_import(args: argparse.Namespace) -> int:
    from camplace.outpaths import check_out_file
    from camplace.validation.camera_io import import_cameras

    check_out_file(args.out, example="cameras.json")
    cams = import_cameras(args.file, args.format, images_dir=args.images, size=args.size)
    cams.save(args.out)
    print(f"wrote {args.out}: {len(cams)} cameras ({cams.format})")
    return EXIT_OK
