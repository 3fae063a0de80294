"""The end-to-end pipeline: instance -> candidates -> visibility -> proven k-camera system.

:func:`run` is a short sequence of stages, each a function of plain data (an Instance, frozen
dataclasses, arrays): :func:`resolve_settings` (defaults and checks -> :class:`RunSettings`),
:func:`sampling_stage` (candidates and points), :func:`visibility_stage` (the matrix),
:func:`solve_stage` (the cameras, robust when asked), :func:`make_solution` (the
:class:`~camplace.solution.Solution`) and :func:`write_stage` (the run folder,
:class:`camplace.RunFolder`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from camplace._io import remove_stale_temps, write_text_atomic
from camplace._progress import Reporter
from camplace.errors import CamplaceError
from camplace.event import event_weights, light_curves_csv, peak_frame
from camplace.names import EVENT_MODES, SAMPLERS
from camplace.sampling import CandidateSet
from camplace.solution import Solution, camera_record, split_timings, team_record, versions
from camplace.visibility.stages import (
    check_input_memory, compute_points, make_run_candidates, stage_seeds, visibility_stage,
)

if TYPE_CHECKING:  # pragma: no cover
    from camplace.visibility.points import TargetPoints

__all__ = ["RunSettings", "degenerate_warnings", "resolve_settings", "run", "run_settings", "sampling_stage", "solve_stage",
           "make_solution", "write_stage"]

log = logging.getLogger(__name__)


def degenerate_warnings(matrix, weights: np.ndarray, k: int, useful: int | None = None) -> list[str]:
    """Plain-language warnings for problems the solver answers trivially.

    ``useful``: the columns that observe a row of positive weight, when already counted
    (:func:`camplace.visibility.summary.summarise`); else counted here in one pass."""
    out = []
    live_rows = weights > 0
    if not live_rows.any():
        out.append("every point weighs 0: nothing can be gained (check the frame weights and target_weight)")
        return out
    if matrix.nnz == 0:
        out.append(
            "no candidate observes any point of the event: check the volume, camera.near_m/far_m, "
            "the occluders and [quality] (incidence limit, light, min_target_px)"
        )
        return out
    if useful is None:
        from camplace.visibility.summary import summarise

        useful = summarise(matrix, weights, []).useful_columns
    if useful < k:
        out.append(
            f"only {useful} candidate(s) observe anything, fewer than k = {k}: the other chosen cameras add "
            "nothing (raise --candidates or widen the volume)"
        )
    return out


def mode_warnings(instance, mode: str) -> list[str]:
    """Plain-language warnings where the solver's mode and the instance's ``[quality]`` meet.

    ``--mode quality`` maximises the weight times the best observation quality; with
    ``[quality] mode = "binary"`` every observed pair has quality 1, so it is maxcover under
    another name (the solver's numbers are left as they are).

    Parameters
    ----------
    instance : Instance
    mode : {"maxcover", "quality", "multiview", "setcover"}

    Returns
    -------
    list of str
    """
    if mode == "quality" and instance.quality.mode == "binary":
        return [
            '--mode quality on an instance with [quality] mode = "binary": every observed pair has quality 1, so the '
            'objective is the observed weight, exactly as --mode maxcover (set [quality] mode = "graded" to weigh '
            "resolution and incidence)"
        ]
    return []


def chosen_view_warnings(instance, cands: CandidateSet, selected: Sequence[int]) -> list[str]:
    """Warnings when the chosen cameras see the target too small to resolve
    (:func:`camplace.visibility.footprint.small_target_warnings`; cameras named by candidate index)."""
    from camplace.visibility.footprint import small_target_warnings

    sel = np.asarray(list(selected), dtype=np.int64)
    if len(sel) == 0:
        return []
    models = None if cands.model is None else np.asarray(cands.model)[sel]
    return small_target_warnings(instance, cands.positions[sel], cands.rotations[sel], labels=[f"candidate {j}" for j in sel],
                                 models=models)


@dataclass(frozen=True)
class RunSettings:
    """Every setting of a run, resolved from the instance's ``[run]`` defaults and checked
    (:func:`resolve_settings`); the parameters of :func:`run` under the same names.

    Attributes
    ----------
    seed, candidates, points, sampler, k, orientations : resolved values
        ``candidates`` positions, ``points`` surface points requested, ``k`` new cameras (the
        instance's k also for setcover, whose solver options have none).
    solve_options : SolveOptions
        The solver's options in one object, the one carrier of mode, k, views, min_angle_deg,
        required_fraction, fixed, forbidden, min_distance_m, engine, time_limit_s and the memory
        budget, passed to :func:`camplace.solver.solve` unchanged (and to the robust stage). The
        attributes of those names read it.
    event_mode : {"all", "peak"}
    matrix_format : {"cpm", "npz"}
    robust : RobustSpec or None
        The instance's ``[robust]`` table unless given.
    cache, dask_address, memory_budget_gb, scratch
        Where and within what memory the visibility matrix is computed (``scratch``: the folder
        of the out-of-core files, default beside the output folder; see
        :mod:`camplace.visibility.scratch`).
    options : dict
        The ``options`` record of ``solution.json`` (:meth:`SolveOptions.record`, the run's
        settings, and ``robust``).
    """

    seed: int
    candidates: int
    points: int
    sampler: str
    k: int
    orientations: int
    solve_options: Any
    event_mode: str = "all"
    matrix_format: str = "cpm"
    robust: Any = None
    cache: bool = True
    dask_address: str | None = None
    memory_budget_gb: float | None = None
    scratch: str | None = None
    options: dict = field(default_factory=dict, compare=False)

    # the solver's options: read from solve_options (one carrier)
    mode = property(lambda self: self.solve_options.mode)
    views = property(lambda self: self.solve_options.views)
    min_angle_deg = property(lambda self: self.solve_options.min_angle_deg)
    required_fraction = property(lambda self: self.solve_options.required_fraction)
    fixed = property(lambda self: self.solve_options.fixed)
    forbidden = property(lambda self: self.solve_options.forbidden)
    min_distance_m = property(lambda self: self.solve_options.min_distance_m)
    engine = property(lambda self: self.solve_options.engine)
    time_limit_s = property(lambda self: self.solve_options.time_limit_s)

    @property
    def memory_budget_bytes(self) -> int | None:
        return None if self.memory_budget_gb is None else int(self.memory_budget_gb * 2**30)


def resolve_settings(
    instance, *, seed: int | None = None, candidates: int | None = None, points: int | None = None,
    sampler: str | None = None, k: int | None = None, time_limit_s: float | None = None, engine: str = "auto",
    orientations: int | None = None, cache: bool = True, dask_address: str | None = None,
    memory_budget_gb: float | None = None, scratch: str | Path | None = None, event_mode: str = "all", mode: str = "maxcover", views: int = 2,
    min_angle_deg: float | None = None, fixed: Sequence[int] = (), forbidden: Sequence[int] = (),
    min_distance_m: float | None = None, required_fraction: float = 1.0, matrix_format: str = "cpm", robust=None,
    solve_options=None,
) -> RunSettings:
    """The settings of a run on ``instance``: the instance's defaults where None, every value checked.

    Parameters are those of :func:`run`; ``solve_options`` (a
    :class:`camplace.solver.options.SolveOptions`) replaces the solver's keyword options, and
    ``k`` / ``time_limit_s`` when set.

    Raises
    ------
    CamplaceError
        One line naming the option and the fix, before anything is computed (including when the
        points and candidate poses alone would not fit the memory budget).
    """
    from camplace.solver.options import SolveOptions

    if solve_options is not None:
        o = solve_options
        mode, views, min_angle_deg, fixed, forbidden = o.mode, o.views, o.min_angle_deg, o.fixed, o.forbidden
        min_distance_m, required_fraction, engine = o.min_distance_m, o.required_fraction, o.engine
        k = k if o.k is None else o.k
        time_limit_s = time_limit_s if o.time_limit_s is None else o.time_limit_s
    if event_mode not in EVENT_MODES:
        raise CamplaceError(f"--event-mode: unknown mode {event_mode!r} (use one of {', '.join(EVENT_MODES)})")
    d = instance.defaults
    seed = d.seed if seed is None else int(seed)
    n_cand = d.candidates if candidates is None else int(candidates)
    n_points = d.points if points is None else int(points)
    sampler = d.sampler if sampler is None else sampler
    k = instance.k if k is None else int(k)
    time_limit_s = d.time_limit_s if time_limit_s is None else float(time_limit_s)
    orientations = d.orientations if orientations is None else int(orientations)
    if orientations < 1:
        raise CamplaceError(f"--orientations: must be >= 1, got {orientations}")
    if sampler not in SAMPLERS:
        raise CamplaceError(f"--sampler: unknown sampler {sampler!r} (use one of {', '.join(SAMPLERS)})")
    if seed < 0:
        raise CamplaceError(f"--seed: must be >= 0, got {seed}")
    if k < 1:
        raise CamplaceError(f"--k: must be >= 1, got {k}")
    if mode != "setcover" and n_cand < k:
        raise CamplaceError(f"--candidates: {n_cand} candidates cannot hold k = {k} cameras (raise --candidates or lower --k)")
    if n_points < 1:
        raise CamplaceError(f"--points: must be >= 1, got {n_points}")
    if matrix_format not in ("cpm", "npz"):
        raise CamplaceError(f"--matrix-format: unknown format {matrix_format!r} (use cpm or npz)")

    check_input_memory(n_points, len(instance.frames), n_cand * orientations, memory_budget_gb)
    if memory_budget_gb is not None and not memory_budget_gb > 0:
        raise CamplaceError(f"--memory-budget-gb: must be > 0, got {memory_budget_gb}")
    # the caller's SolveOptions with the run's defaults filled in (its other fields, e.g. the
    # setcover search seed, go through unchanged), or one made from the keyword options
    solve_opts = (solve_options or SolveOptions()).replace(
        mode=mode, k=None if mode == "setcover" else k, views=views, min_angle_deg=min_angle_deg,
        required_fraction=required_fraction, fixed=tuple(fixed), forbidden=tuple(forbidden),
        min_distance_m=min_distance_m, engine=engine, time_limit_s=time_limit_s,
        memory_budget_bytes=(int(memory_budget_gb * 2**30) if memory_budget_gb is not None
                             else None if solve_options is None else solve_options.memory_budget_bytes),
    )
    options = {**solve_opts.record(), "event_mode": event_mode, "sampler": sampler, "seed": seed, "candidates": n_cand,
               "points": n_points, "orientations": orientations}
    robust = instance.robust if robust is None else robust
    if robust is not None:
        from camplace.robust import check_request, spec_record

        check_request(robust, mode, min_angle_deg, engine)
        options["robust"] = spec_record(robust)
    return RunSettings(
        seed=seed, candidates=n_cand, points=n_points, sampler=sampler, k=k, orientations=orientations,
        solve_options=solve_opts, event_mode=event_mode, matrix_format=matrix_format, robust=robust, cache=cache,
        dask_address=dask_address, memory_budget_gb=memory_budget_gb,
        scratch=None if scratch is None else str(scratch), options=options,
    )


def run(
    instance,
    *,
    seed: int | None = None,
    candidates: int | None = None,
    points: int | None = None,
    sampler: str | None = None,
    k: int | None = None,
    time_limit_s: float | None = None,
    engine: str = "auto",
    orientations: int | None = None,
    outdir: str | Path | None = None,
    reporter: Reporter | None = None,
    cache: bool = True,
    dask_address: str | None = None,
    memory_budget_gb: float | None = None,
    scratch: str | Path | None = None,
    event_mode: str = "all",
    mode: str = "maxcover",
    views: int = 2,
    min_angle_deg: float | None = None,
    fixed: tuple[int, ...] = (),
    forbidden: tuple[int, ...] = (),
    min_distance_m: float | None = None,
    required_fraction: float = 1.0,
    matrix_format: str = "cpm",
    robust=None,
    solve_options=None,
    threads: int | None = None,
) -> Solution:
    """Run the whole pipeline on an instance.

    Parameters
    ----------
    instance : Instance or str
        An :class:`~camplace.instance.Instance`, a built-in name or an instance file path.
    seed, candidates, points, sampler, k, time_limit_s : optional
        Override the instance's run defaults.
    engine : str
        Solver engine ("auto", "exact", "mip", "cpsat").
    orientations : int or None
        Poses per candidate position (default: the instance's ``run.orientations``).
    outdir : path or None
        When given, write solution.json, candidates.csv, points.csv, visibility.cpm and scene.ply there.
    reporter : Reporter or None
        Progress display (silent by default).
    cache : bool
        Reuse a cached visibility matrix for identical inputs (see :mod:`camplace.visibility.cache`).
    dask_address : str or None
        Compute the visibility matrix on a Dask cluster (scheduler address or ``local:N``).
    memory_budget_gb : float or None
        Stop before computing a visibility matrix estimated to need more memory (default: half the RAM);
        also caps the solver's engines and models (which otherwise use 60 % of the memory available).
        A binary matrix whose column bitsets (or a graded one whose bytes) do not fit it is kept
        out of core instead, in ``scratch``.
    scratch : path or None
        Folder for the out-of-core files (default: beside ``outdir``, else the system's temporary
        folder); a temporary folder made in it is removed when the run ends, however it ends.
    event_mode : {"all", "peak"}
        ``all`` maximises the expected coverage over all frames (weights P(t)); ``peak`` places the
        cameras for the maximum-likelihood frame alone (the thesis's PS01).
    mode : {"maxcover", "quality", "multiview", "setcover"}
        The formulation (see :func:`camplace.solver.api.solve`): the observed weight, the weight
        times the best quality, the weight seen by at least ``views`` cameras (optionally
        ``min_angle_deg`` apart), or the fewest cameras observing ``required_fraction`` of it.
    views, min_angle_deg, fixed, forbidden, min_distance_m, required_fraction : optional
        Options of the formulation: existing cameras kept (``fixed`` column indices, added to the
        k new ones), candidates never used, a minimum distance between chosen cameras.
    matrix_format : {"cpm", "npz"}
        The matrix file in ``outdir``: ``visibility.cpm`` (:mod:`camplace.visibility.store`) or
        ``visibility.npz`` (``scipy.sparse.load_npz``).
    robust : RobustSpec or None
        Optimise against installation error (:mod:`camplace.robust`); default: the instance's
        ``[robust]`` table, if any.
    solve_options : SolveOptions or None
        The solver's options in one object (:class:`camplace.solver.options.SolveOptions`, as the
        command line builds them); they replace ``mode``, ``views``, ``min_angle_deg``, ``fixed``,
        ``forbidden``, ``min_distance_m``, ``required_fraction`` and ``engine``, and ``k`` /
        ``time_limit_s`` when set (otherwise the keyword or the instance's default).
    threads : int or None
        Threads every stage may use (Embree casting, the matrix store, the solver's kernels and
        searches, OR-Tools' workers): 1 to the cores this process may use, as ``--threads``;
        default: the process's setting (:func:`camplace._cores.set_threads`), else every allowed
        core. The matrix and the exact engine's answer are the same at every count.

    Returns
    -------
    Solution
    """
    from camplace._cores import check_threads, using_threads
    from camplace.instance import resolve_instance

    try:
        check_threads(threads)
    except ValueError as e:
        raise CamplaceError(str(e)) from None

    if not hasattr(instance, "frames"):
        instance = resolve_instance(str(instance), seed=seed)
    settings = resolve_settings(
        instance, seed=seed, candidates=candidates, points=points, sampler=sampler, k=k, time_limit_s=time_limit_s,
        engine=engine, orientations=orientations, cache=cache, dask_address=dask_address,
        memory_budget_gb=memory_budget_gb, scratch=scratch, event_mode=event_mode, mode=mode, views=views,
        min_angle_deg=min_angle_deg, fixed=fixed, forbidden=forbidden, min_distance_m=min_distance_m, required_fraction=required_fraction,
        matrix_format=matrix_format, robust=robust, solve_options=solve_options,
    )
    with using_threads(threads):
        return run_settings(instance, settings, outdir=outdir, reporter=reporter)


def _solver_warm_up(instance, settings: RunSettings):
    """What the visibility stage's waiting thread can do for the solve: load the kernels of plain
    max coverage on column bitsets (:func:`camplace.solver.bits_route.load_kernels`) when the
    matrix is binary, the run has no team and no robust stage; else None."""
    if instance.quality.mode == "graded" or getattr(instance, "team", None) is not None or settings.robust is not None:
        return None
    from camplace.solver.bits_route import load_kernels

    return lambda: load_kernels(settings.solve_options)


def _while_casting(instance, settings: RunSettings, cands: CandidateSet, pts, write: bool):
    """The visibility stage's ``idle`` work: the solver's kernels (:func:`_solver_warm_up`), then,
    for a run that writes a folder, the text of ``candidates.csv`` and ``points.csv`` (kept on the
    sets: :meth:`CandidateSet.to_csv`), so that neither waits in a serial stage after the cast.
    None when there is nothing to do."""
    warm = _solver_warm_up(instance, settings)
    if warm is None and not write:
        return None

    def work() -> None:
        if warm is not None:
            warm()
        if write:
            cands.to_csv()
            pts.to_csv()

    return work


def run_settings(instance, settings: RunSettings, *, outdir: str | Path | None = None,
                 reporter: Reporter | None = None) -> Solution:
    """The pipeline as a sequence of stages: sampling, visibility, solve, the solution, the folder.

    Parameters
    ----------
    instance : Instance
    settings : RunSettings
        Resolved and checked (:func:`resolve_settings`).
    outdir : path or None
        When given, the run folder to write (:func:`write_stage`).
    reporter : Reporter or None

    Returns
    -------
    Solution
    """
    if outdir is not None:
        from camplace.outpaths import check_out_folder

        check_out_folder(outdir, "outdir")  # a file there is an error before the work, not after
    reporter = reporter or Reporter()
    for note in mode_warnings(instance, settings.mode):
        log.warning("%s", note)
    timings: dict[str, float] = {}
    t0 = first_stage_at = time.perf_counter()
    with reporter.stage("sampling"):
        cands, pts = sampling_stage(instance, settings)
    timings["sampling"] = time.perf_counter() - t0

    from camplace.visibility.scratch import Scratch

    solve_bytes = None if settings.robust is not None else guard_solve_bytes(len(pts), cands, settings.solve_options)

    parent = settings.scratch if settings.scratch is not None else (Path(outdir).resolve().parent if outdir is not None
                                                                    else None)
    with Scratch(parent) as scratch:  # out-of-core files, removed however the run ends
        t0 = time.perf_counter()
        vis = visibility_stage(instance, cands, pts, reporter=reporter, cache=settings.cache,
                               dask_address=settings.dask_address, memory_budget_gb=settings.memory_budget_gb,
                               scratch=scratch, solve_mode=settings.mode,
                               idle=_while_casting(instance, settings, cands, pts, outdir is not None),
                               solve_bytes=solve_bytes)
        timings["visibility"] = time.perf_counter() - t0
        timings.update(vis.timings_s)  # cache.load / cache.store (inside the visibility stage)

        res, robust_record = solve_stage(instance, cands, pts, vis.pattern, settings, reporter=reporter,
                                         timings=timings)
        solution = make_solution(instance, settings, cands, vis, res, robust_record, timings)
        if outdir is not None:
            write_stage(outdir, instance, solution, matrix_format=settings.matrix_format, reporter=reporter,
                        first_stage_at=first_stage_at)
    return solution


def guard_solve_bytes(m: int, cands: CandidateSet, o) -> Callable[[float], int]:
    """The working bytes of the solve a binary run makes next, for the visibility stage's memory
    guard: :func:`camplace.solver.api.bits_solve_bytes` of the options ``o`` on ``m`` points and the
    candidates, as a function of the observed share of cells (the guard's pilot measures it),
    with the candidate pairs closer than ``o.min_distance_m`` counted from their positions."""
    from camplace.solver.api import bits_solve_bytes, conflict_count

    n = len(cands)
    conflicts = 0 if o.min_distance_m is None else conflict_count(np.asarray(cands.positions, dtype=np.float64),
                                                                  float(o.min_distance_m))

    def solve_bytes(density: float) -> int:
        return bits_solve_bytes(m, n, o, int(round(float(density) * m * n)), conflicts)

    return solve_bytes


def sampling_stage(instance, settings: RunSettings) -> tuple[CandidateSet, "TargetPoints"]:
    """The candidate poses (the columns) and target points (the rows) of a run.

    Returns
    -------
    candidates : CandidateSet
        ``settings.candidates * settings.orientations`` poses (fewer orientations when aims coincide).
    points : TargetPoints
    """
    cand_seed, _ = stage_seeds(settings.seed)
    cands = make_run_candidates(instance, settings.sampler, settings.candidates, settings.orientations, cand_seed)
    cands = cands.with_run(settings.sampler, settings.seed)
    return cands, compute_points(instance, settings.points, settings.seed)


def solve_stage(instance, cands: CandidateSet, pts, matrix, settings: RunSettings, *,
                reporter: Reporter | None = None, timings: dict[str, float] | None = None):
    """Choose the cameras (:func:`camplace.solver.api.solve`), and against installation error when
    the run is robust (:func:`camplace.robust.robust_stage`).

    Parameters
    ----------
    instance : Instance
    cands : CandidateSet
    pts : TargetPoints
    matrix : (m, n) scipy.sparse.csr_matrix, camplace.visibility.bits.BitMatrix or camplace.visibility.qbytes.ByteMatrix
        A binary matrix as column bitsets, a graded one as quantised columns, goes to the solver as
        it is (no CSR is made for the routes that read them; the others convert it).
    settings : RunSettings
    reporter : Reporter or None
    timings : dict or None
        Receives ``solve`` (and the robust stage's timings), seconds.

    Returns
    -------
    result : SolveResult
    robust_record : dict or None
        The ``robust`` entry of ``solution.json``.
    """
    from camplace.solver.api import solve

    reporter = reporter or Reporter()
    timings = {} if timings is None else timings
    s = settings
    weights = event_weights(pts, instance, s.event_mode)
    geometric = s.solve_options.reads_geometry
    t0 = time.perf_counter()
    from camplace.solver.problem.team import team_options

    opts = team_options(getattr(instance, "team", None), cands, s.solve_options)  # issue 31: the team's constraints
    with reporter.stage("solve"):
        res = solve(matrix, weights, positions=cands.positions if geometric else None,
                    points=pts.positions if geometric else None, options=opts)
    timings["solve"] = time.perf_counter() - t0
    if s.robust is None:
        return res, None
    from camplace.robust import robust_stage

    if getattr(matrix, "format", None) == "bytes":  # the robust stage reads CSR values
        matrix = matrix.tocsr()

    return robust_stage(
        instance, cands, pts, matrix, weights, res, s.robust, opts, seed=s.seed, cache=s.cache,
        reporter=reporter, timings=timings,
    )


def make_solution(instance, settings: RunSettings, cands: CandidateSet, vis, res, robust_record: dict | None,
                  timings: dict[str, float]) -> Solution:
    """The :class:`Solution` of a run: the solver's answer with the coverage figures, the camera
    records, warnings and the solver's timings (moved from its stats into ``timings``).

    The warnings are the instance's (``Instance.warnings``, logged when it was read), the mode's
    (:func:`mode_warnings`, logged when the run started) and the degenerate problems'
    (:func:`degenerate_warnings`)."""
    s = settings
    pts = vis.points
    weights = event_weights(pts, instance, s.event_mode)
    # the system's size: the fixed cameras plus the new ones (setcover: as many as it needed)
    enforced = "team" in res.stats  # the solver enforced the team's constraints (issue 31)
    budget_team = enforced and res.stats["team"].get("cardinality") == "budget"
    k = len(res.selected) if (s.mode == "setcover" or s.fixed or budget_team) else s.k
    from camplace.visibility.summary import summarise

    t0 = time.perf_counter()
    summary = summarise(vis.pattern, weights, res.selected, pts.frame, pts.weight, len(instance.frames))
    degenerate = degenerate_warnings(vis.pattern, weights, k, summary.useful_columns)
    degenerate += chosen_view_warnings(instance, cands, res.selected)
    timings["summary"] = time.perf_counter() - t0
    for note in degenerate:
        log.info("%s", note)
    cameras = [camera_record(instance, cands, j) for j in res.selected]
    team, team_notes = team_record(instance, cameras, enforced=enforced,
                                   cardinality=res.stats["team"].get("cardinality") if enforced else None)
    for note in team_notes:
        log.warning("%s", note)
    notes = [*instance.warnings, *mode_warnings(instance, s.mode), *degenerate, *team_notes]
    solver_stats, solver_times = split_timings(dict(res.stats))
    timings.update(solver_times)
    total_weight = float(weights.sum())
    observed = summary.covered
    peak = peak_frame(instance)
    in_peak = pts.frame == peak
    # no incumbent at all (a time limit before the first solution): objective 0, gap 100%
    bound = float(res.bound) if np.isfinite(res.bound) else total_weight
    gap = float(res.gap) if np.isfinite(res.gap) else 1.0
    return Solution(
        status=res.status,
        objective=float(res.objective) if np.isfinite(res.objective) else 0.0,  # an infeasible team: no cameras
        bound=bound,
        gap=gap,
        k=k,
        seed=s.seed,
        sampler=s.sampler,
        n_candidates=len(cands),
        n_points=len(pts),
        coverage_fraction=float(weights[observed].sum()) / total_weight if total_weight > 0 else 0.0,
        timings_s=timings,
        versions=versions(),
        cameras=cameras,
        instance=instance.name,
        engine=res.engine,
        mode=s.mode,
        solver_stats=solver_stats,
        warnings=notes,
        event_mode=s.event_mode,
        peak_frame=peak,
        expected_coverage=float(pts.weight[observed].sum() / pts.weight.sum()),
        peak_coverage=float(pts.weight[observed & in_peak].sum() / max(pts.weight[in_peak].sum(), 1e-300)),
        points_requested=s.points,
        options=s.options,
        robust=robust_record,
        team=team,
        candidates=cands,
        visibility=vis,
        light_curves=summary.seen,
    )


def write_stage(outdir: str | Path, instance, solution: Solution, *, matrix_format: str = "cpm",
                reporter: Reporter | None = None, first_stage_at: float | None = None) -> None:
    """Write a run folder (:class:`camplace.RunFolder`): scene.ply, instance.toml, candidates.csv, the
    matrix, points.csv, light_curves.csv, and solution.json last (its presence means the outputs are
    complete). Adds ``write`` and ``write.matrix`` to ``solution.timings_s``, and with
    ``first_stage_at`` (``time.perf_counter()`` when the run's first stage began) the whole process's
    ``startup``, ``setup``, ``process.wall`` and ``process.untimed`` (:func:`camplace._clock.account`)."""
    from camplace.outpaths import check_out_folder
    from camplace.runfolder import RunFolder
    from camplace.visibility import frame_scene, write_ply

    reporter = reporter or Reporter()
    timings = solution.timings_s
    vis = solution.visibility
    t0 = time.perf_counter()
    with reporter.stage("write"):
        folder = RunFolder(check_out_folder(outdir, "outdir"))  # a file is no folder (RunFolder would take its parent)
        folder.path.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(folder.path)
        write_ply(folder.file("scene.ply"), frame_scene(instance, 0).triangles)
        folder.save_instance(instance)
        folder.save_candidates(solution.candidates)
        t1 = time.perf_counter()
        folder.save_visibility(vis, matrix_format)
        timings["write.matrix"] = time.perf_counter() - t1
        folder.save_points(vis.points)
        write_text_atomic(folder.file("light_curves.csv"), light_curves_csv(instance, vis, solution.selected,
                                                                            solution.light_curves))
        timings["write"] = time.perf_counter() - t0
        if first_stage_at is not None:
            from camplace._clock import account

            account(timings, first_stage_at)
        folder.save_solution(solution)
