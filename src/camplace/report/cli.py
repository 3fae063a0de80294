"""Verbs of the report stage: ``campaign``, ``report``, ``export`` (and its deprecated alias ``export-cameras``).

Imports nothing heavy at module level (matplotlib, OpenCV and Embree load when a verb runs).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable

from camplace.errors import CamplaceError, EXIT_OK
from camplace.names import CAMERA_FORMATS, EVENT_MODES, EXPORT_FORMATS, EXPORT_FRAMES, SAMPLERS



def register(subparsers, add_run_options: Callable[[argparse.ArgumentParser], None]) -> dict[str, Callable[[argparse.Namespace], int]]:
    """Add the report verbs to ``subparsers``; returns {verb: handler}."""
    p = subparsers.add_parser("campaign", help="score N random k-camera systems with the solver's objective and the thesis's legacy score")
    p.add_argument("instance", help="a run's output folder (takes its instance, seed, rows, k, aims and event mode), "
                                    "a built-in instance name or an instance .toml file")
    p.add_argument("--systems", type=int, required=True, help="number of random systems N")
    p.add_argument("--sampler", choices=SAMPLERS, default="uniform", help="sampler of the camera positions (default uniform)")
    p.add_argument("--seed", type=int, default=None, help="seed of the positions and of the rows (default: the instance's; not with a run folder)")
    p.add_argument("--points", type=int, default=None, help="surface points requested, as 'camplace run --points' (default: the instance's; not with a run folder)")
    p.add_argument("--k", type=int, default=None, help="cameras per system (default: the instance's k; not with a run folder)")
    p.add_argument("--orientations", type=int, default=None, help="aim points; each camera aims at one at random (default: the instance's; not with a run folder)")
    p.add_argument("--event-mode", choices=EVENT_MODES, default=None, dest="event_mode",
                   help="row weights of the objective, as 'camplace run --event-mode' (default all; not with a run folder)")
    p.add_argument("--legacy-omega", type=float, default=0.0, dest="legacy_omega", help="Algorithm 2's camera angle, added to its FoV as given (default 0)")
    p.add_argument("--no-cache", action="store_true", help="do not reuse or store cached visibility matrices")
    p.add_argument("-o", "--out", type=Path, default=None,
                   help="campaign folder (default with a run folder: OUTDIR/campaign-SAMPLER, which OUTDIR's report includes)")
    p.add_argument("--force", action="store_true",
                   help="replace a campaign in the folder that has more systems than --systems (without it that is an error)")

    p = subparsers.add_parser("report", help="write OUTDIR/report.html: optimised system, campaigns, samplers, vision cones, validation")
    p.add_argument("outdir", type=Path, help="output folder of 'camplace run' (campaign folders inside it are included)")
    p.add_argument("--union", choices=["auto", "always"], default="auto",
                   help="re-solve over the run's candidates plus the campaign cameras only when a campaign system beats the run's (auto, default) or always")
    p.add_argument("--no-sampler-study", action="store_false", dest="sampler_study", help="skip the samplers' best objective against candidates")
    p.add_argument("--samplers", default="chaotic,sobol,uniform", help="samplers of that study (default chaotic,sobol,uniform)")
    p.add_argument("--ladder", default=None, help="candidate-position counts of that study, e.g. 50,200,1000 (default 25,50,100,200,500,1000,... up to the run's)")
    p.add_argument("--time-limit", type=float, default=None, dest="time_limit", help="seconds per solve (default: the instance's, at most 20 s in the study)")
    p.add_argument("--no-cache", action="store_true", help="do not reuse or store cached visibility matrices")
    p.add_argument("-o", "--out", type=Path, default=None, help="HTML file to write (default OUTDIR/report.html)")

    p = subparsers.add_parser("export", help="write the chosen cameras: lab placement (CSV + JSON, default) and/or JSON, CSV, COLMAP, GLB camera files")
    p.add_argument("outdir", type=Path, help="output folder of 'camplace run'")
    p.add_argument("--format", default="placement", dest="formats",
                   help=f"{', '.join(EXPORT_FORMATS)}, or all (= {','.join(CAMERA_FORMATS)}); comma-separated for several (default placement)")
    p.add_argument("--frame", choices=EXPORT_FRAMES, default=None,
                   help="placement: coordinate frame (default physical); the camera files are in the simulation frame")
    p.add_argument("--transform", type=Path, default=None, help="placement: TOML/JSON with the [transform] table (default: the run's instance.toml)")
    _add_camera_file_options(p)
    p.add_argument("-o", "--out", type=Path, default=None, help="output folder (default: OUTDIR for placement, OUTDIR/export for camera files)")

    p = subparsers.add_parser("export-cameras", help="deprecated: use 'export --format all' (or json, csv, colmap, glb)")
    p.add_argument("outdir", type=Path, help="output folder of 'camplace run'")
    p.add_argument("--format", default="all", dest="formats", help="json, csv, colmap, glb, or all (default); comma-separated for several")
    _add_camera_file_options(p)
    p.add_argument("-o", "--out", type=Path, default=None, help="output folder (default OUTDIR/export)")

    return {"campaign": _cmd_campaign, "report": _cmd_report, "export": _cmd_export, "export-cameras": _cmd_export_cameras}


def _add_camera_file_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--experiment", default=None, help="camera files: experiment name in camera names (default: the instance name)")
    p.add_argument("--frustum-depth", type=float, default=None, dest="frustum_depth", help="glb: frustum depth, metres (default: distance to the aim point)")
    p.add_argument("--phase", type=int, default=None, help="camera files: the moving agents' poses of this phase of plan.json (default out: OUTDIR/export-phaseP)")


def _csv_list(text: str, what: str) -> list[str]:
    items = [s.strip() for s in text.split(",") if s.strip()]
    if not items:
        raise CamplaceError(f"{what}: give at least one value (comma-separated)")
    return items


def _check_campaign_out(out: Path, systems: int, force: bool) -> str:
    """``campaign``'s folder, before any work; returns a note on the campaign it replaces ("" if none).

    The folder must be a folder. A campaign already in it with more systems than ``systems`` is
    kept unless ``force`` (a quick campaign of 50 systems must not silently replace the 200 of
    ``run --report``): an error names both ways out. A campaign of as many systems or fewer is
    replaced, and the note says so.
    """
    import json

    from camplace.outpaths import check_out_folder
    from camplace.report.campaign import CAMPAIGN_FILES

    check_out_folder(out, files=CAMPAIGN_FILES)
    existing = out / "campaign.json"
    if not existing.is_file():
        return ""
    try:
        old = json.loads(existing.read_text())
        n_old, what = int(old["n_systems"]), f"a campaign of {old['n_systems']} {old['sampler']} systems"
    except (OSError, ValueError, KeyError, TypeError):
        n_old, what = 0, "an unreadable campaign"
    if n_old > systems and not force:
        raise CamplaceError(f"--systems: {out} already holds {what}, more than {systems} (add --force to replace it, "
                            f"or write this one elsewhere with -o DIR)")
    return f"replaced {what} in {out}"


def _cmd_campaign(args: argparse.Namespace) -> int:
    from camplace._progress import ConsoleReporter
    from camplace.report.campaign import CAMPAIGN_FILES, campaign_for_run, run_campaign

    source = Path(args.instance)
    if source.is_dir():
        from camplace.report.compare import load_run_data

        given = [f"--{name.replace('_', '-')}" for name in ("seed", "points", "k", "orientations", "event_mode")
                 if getattr(args, name) is not None]
        if given:
            raise CamplaceError(f"{', '.join(given)}: a run folder fixes them (its campaign must score the run's rows "
                                f"with the run's k); drop them, or give an instance instead of {source}")
        if args.out is None:
            args.out = source / f"campaign-{args.sampler}"
        replaced = _check_campaign_out(args.out, args.systems, args.force)
        run = load_run_data(source)
        camp = campaign_for_run(run, systems=args.systems, sampler=args.sampler, legacy_omega=args.legacy_omega,
                                outdir=args.out, cache=not args.no_cache, reporter=ConsoleReporter())
    else:
        if args.out is None:
            raise CamplaceError("--out: required with an instance (or give a run folder: 'camplace campaign OUTDIR --systems N')")
        replaced = _check_campaign_out(args.out, args.systems, args.force)
        camp = run_campaign(
            args.instance, systems=args.systems, sampler=args.sampler, seed=args.seed, points=args.points, k=args.k,
            orientations=args.orientations, legacy_omega=args.legacy_omega, event_mode=args.event_mode or "all",
            outdir=args.out, cache=not args.no_cache, reporter=ConsoleReporter(),
        )
    s = camp.summary()
    o = s["objective"]
    print(f"{camp.n_systems} random {camp.k}-camera systems ({camp.sampler}, seed {camp.seed}): objective min {o['min']:.4f}, "
          f"median {o['median']:.4f}, max {o['max']:.4f} (system {s['best_system']})")
    rho = s["spearman_legacy_vs_objective"]
    print(f"legacy score: best system {s['best_legacy_system']} (objective {camp.objective[s['best_legacy_system'] - 1]:.4f}); "
          f"Spearman rho vs objective {'-' if rho is None else f'{rho:.3f}'}")
    print(f"wrote {args.out}/{', '.join(CAMPAIGN_FILES)}" + (f" ({replaced})" if replaced else ""))
    return EXIT_OK


def _cmd_report(args: argparse.Namespace) -> int:
    from camplace._progress import ConsoleReporter
    from camplace.report.build import write_report

    ladder = None
    if args.ladder is not None:
        try:
            ladder = [int(x) for x in _csv_list(args.ladder, "--ladder")]
        except ValueError:
            raise CamplaceError(f"--ladder: use whole numbers such as 50,200,1000, got {args.ladder!r}") from None
    if args.time_limit is not None and not args.time_limit > 0:
        raise CamplaceError(f"--time-limit: must be > 0 seconds, got {args.time_limit}")
    from camplace.outpaths import check_out_file
    from camplace.report.build import REPORT_NAME
    from camplace.report.figures import require_matplotlib

    require_matplotlib()
    check_out_file(args.out if args.out is not None else args.outdir / REPORT_NAME, example=REPORT_NAME)
    path = write_report(
        args.outdir, out=args.out, union=args.union, sampler_study=args.sampler_study,
        samplers=_csv_list(args.samplers, "--samplers"), ladder=ladder, time_limit_s=args.time_limit,
        cache=not args.no_cache, reporter=ConsoleReporter(),
    )
    print(f"wrote {path}")
    return EXIT_OK


def export_formats(spec: str) -> tuple[str, ...]:
    """``--format`` of ``camplace export``: a comma list of :data:`camplace.names.EXPORT_FORMATS`
    (``all`` = the camera files) -> formats in canonical order."""
    names = {s.strip().lower() for s in spec.split(",") if s.strip()}
    if "all" in names:
        names = (names - {"all"}) | set(CAMERA_FORMATS)
    bad = sorted(names - set(EXPORT_FORMATS))
    if bad or not names:
        what = f"unknown format {bad[0]!r}" if bad else "no format given"
        raise CamplaceError(f"--format: {what} (use {', '.join(EXPORT_FORMATS)} or all, comma-separated)")
    return tuple(f for f in EXPORT_FORMATS if f in names)


def _cmd_export(args: argparse.Namespace) -> int:
    fmts = export_formats(args.formats)
    files = tuple(f for f in fmts if f in CAMERA_FORMATS)
    placement = "placement" in fmts
    if not placement and args.frame == "physical":
        raise CamplaceError("--frame physical: the camera files (json, csv, colmap, glb) are in the simulation frame; add placement to --format for lab coordinates")
    if not placement and args.transform is not None:
        raise CamplaceError("--transform: applies to --format placement only")
    if placement and args.phase is not None:
        raise CamplaceError("--phase: applies to the camera files only (the placement is of the run's cameras); drop placement from --format")
    for option, value in (("--experiment", args.experiment), ("--frustum-depth", args.frustum_depth)):
        if not files and value is not None:
            raise CamplaceError(f"{option}: applies to the camera files (--format {','.join(CAMERA_FORMATS)}), not to placement")
    if args.frustum_depth is not None and not args.frustum_depth > 0:
        raise CamplaceError(f"--frustum-depth: must be > 0 metres, got {args.frustum_depth}")
    _check_export_out(args, placement, files)
    if placement:
        from camplace.validation.workflow import export_run

        frame, transform, source = _placement_frame(args)
        csv_path, json_path = export_run(args.outdir, frame=frame, transform=transform, transform_source=source, out=args.out)
        print(f"wrote {csv_path} and {json_path}")
    if files:
        _write_camera_files(args, files)
    return EXIT_OK


def _check_export_out(args: argparse.Namespace, placement: bool, files: tuple[str, ...]) -> None:
    """``export``'s output folders (``-o``, else each format's default), before any work."""
    from camplace.outpaths import check_out_folder

    if args.out is not None:
        check_out_folder(args.out)
        return
    if placement:
        check_out_folder(args.outdir, "OUTDIR")
    if files:
        check_out_folder(_camera_files_folder(args), "OUTDIR")


def _camera_files_folder(args: argparse.Namespace) -> Path:
    """Where the camera files go: ``-o``, else ``OUTDIR/export`` (``OUTDIR/export-phaseP`` with ``--phase``)."""
    from camplace.report.export import default_export_folder

    return args.out if args.out is not None else default_export_folder(args.outdir, args.phase)


def _placement_frame(args: argparse.Namespace) -> tuple[str, object, str]:
    """The placement's frame, ``[transform]`` table and its source, from ``--frame`` and ``--transform``.

    Without ``--frame``: the physical frame when a ``[transform]`` table is at hand (``--transform``
    or the run's instance.toml), else the simulation frame, with one ``warning:`` line (plain
    ``camplace export OUTDIR`` then writes something useful instead of failing).
    """
    import sys

    from camplace.validation.workflow import read_table_file

    if args.transform is not None:
        return args.frame or "physical", read_table_file(args.transform, "transform"), f"{args.transform}: [transform]"
    if args.frame is not None:
        return args.frame, None, ""
    from camplace.runfolder import INSTANCE_NAME, RunFolder

    transform = RunFolder(args.outdir).instance.transform
    if transform is not None:
        return "physical", transform, f"{args.outdir / INSTANCE_NAME}: [transform]"
    print(f"warning: {args.outdir / INSTANCE_NAME} has no [transform] table: the placement is in the run's own "
          f"coordinates (placement.simulation.*); for lab coordinates pass --transform FILE (see docs/validation.md)",
          file=sys.stderr)
    return "simulation", None, ""


def _write_camera_files(args: argparse.Namespace, formats) -> None:
    from camplace.report.export import export_cameras

    paths = export_cameras(args.outdir, formats=formats, out=_camera_files_folder(args), experiment=args.experiment,
                           frustum_depth_m=args.frustum_depth, phase=args.phase)
    for p in paths:
        print(f"wrote {p}")


def _cmd_export_cameras(args: argparse.Namespace) -> int:
    import sys

    print("warning: 'camplace export-cameras' is deprecated and will be removed in the next release: "
          "use 'camplace export OUTDIR --format all' (or json, csv, colmap, glb)", file=sys.stderr)
    from camplace.outpaths import check_out_folder

    check_out_folder(_camera_files_folder(args), "-o/--out" if args.out is not None else "OUTDIR")
    _write_camera_files(args, args.formats)
    return EXIT_OK
