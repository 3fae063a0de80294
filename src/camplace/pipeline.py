"""The end-to-end pipeline: instance -> candidates -> visibility -> proven k-camera system."""

from __future__ import annotations

import logging
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camplace._io import read_json, remove_stale_temps, write_json_atomic, write_text_atomic
from camplace._progress import Reporter
from camplace.errors import CamplaceError
from camplace.sampling import SAMPLERS, CandidateSet
from camplace.visibility import VisibilityMatrix, compute_visibility, frame_scene, make_target_points, write_ply

log = logging.getLogger(__name__)


def versions() -> dict[str, str]:
    """Versions of camplace and the libraries that shape its results."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for dist in ("camplace", "numpy", "scipy", "ortools", "embreex", "trimesh"):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "unknown"
    return out


@dataclass(frozen=True, eq=False)
class Solution:
    """The chosen camera system and how good it provably is (the content of ``solution.json``).

    Attributes
    ----------
    status : str
        "optimal" | "feasible" | "infeasible" | "unknown".
    objective : float
        Weight of the points observed by the chosen cameras (points weigh 1 in total).
    bound : float
        Proven upper bound on the objective of any k-camera system from these candidates.
    gap : float
        (bound - objective) / bound.
    k : int
        Cameras in the system (fixed ones included; for setcover, as many as were needed).
    seed, sampler, n_candidates : as run
    n_points : int
        Rows of the visibility matrix (``points.csv``): the surface points of every frame plus the
        emitter points. This is THE meaning of ``n_points`` everywhere (run, campaign, report);
        the ``--points`` value that produced them is ``points_requested``.
    coverage_fraction : float
        Observed weight / total point weight.
    timings_s : dict of str to float
        Wall time per stage.
    versions : dict of str to str
    cameras : list of dict
        Per chosen camera: candidate (column index), position [x, y, z], rotation (3x3,
        world-from-camera, OpenCV axes), K (3x3), width, height, near_m, far_m.
    instance : str
        Instance name.
    engine : str
        Solver engine that produced the answer.
    mode : str
        The formulation solved (``maxcover``, ``quality``, ``multiview``, ``setcover``); for
        ``setcover`` the objective is the number (or cost) of cameras and ``bound`` a lower bound.
    event_mode : str
        ``all``: the objective is the expected coverage over all frames (weights P(t));
        ``peak``: the coverage of the maximum-likelihood frame alone.
    peak_frame : int
        The maximum-likelihood frame (for the volcano, the plume's peak step).
    expected_coverage : float
        Share of the whole event (all frames, weighted by P) the chosen cameras observe.
    peak_coverage : float
        Share of the peak frame's weight the chosen cameras observe.
    warnings : list of str
        Degenerate situations worth a look: nothing observable, fewer useful candidates than k,
        all weights zero.
    points_requested : int
        The ``--points`` value of the run (surface points split over the frames, before rounding
        up to a whole number per frame and adding emitters); with ``seed`` it recreates the rows.
    options : dict
        Every option that shaped the answer, as asked for (:meth:`camplace.solver.options.SolveOptions.record` and the run's settings): ``mode``, ``k``,
        ``views``, ``min_angle_deg``, ``required_fraction``, ``fixed``, ``forbidden``,
        ``min_distance_m``, ``engine``, ``time_limit_s``, ``event_mode``, ``sampler``, ``seed``,
        ``candidates``, ``points``, ``orientations`` (and ``robust``, the settings of a robust run).
        With ``points.csv`` and the matrix they recompute the objective from the folder alone.
    robust : dict or None
        Robust runs (``[robust]``, ``--pose-error``): settings, the sampled objective of the chosen
        system and of the nominal optimum, and both on fresh installations
        (:func:`camplace.robust.robust_stage`). ``objective``/``bound``/``gap`` are then those of the
        robust objective; the coverage figures are the chosen system's at the nominal poses.
    candidates, visibility : optional
        The run's CandidateSet and VisibilityMatrix (not part of ``solution.json``).
    """

    status: str
    objective: float
    bound: float
    gap: float
    k: int
    seed: int
    sampler: str
    n_candidates: int
    n_points: int
    coverage_fraction: float
    timings_s: dict
    versions: dict
    cameras: list
    instance: str = ""
    engine: str = ""
    mode: str = "maxcover"
    solver_stats: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    event_mode: str = "all"
    peak_frame: int = 0
    expected_coverage: float = 0.0
    peak_coverage: float = 0.0
    points_requested: int = 0
    options: dict = field(default_factory=dict)
    robust: dict | None = None
    candidates: CandidateSet | None = field(default=None, repr=False)
    visibility: VisibilityMatrix | None = field(default=None, repr=False)

    @property
    def selected(self) -> list[int]:
        """Column indices of the chosen cameras."""
        return [int(c["candidate"]) for c in self.cameras]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content of ``solution.json``."""
        return {
            "status": self.status,
            "objective": self.objective,
            "bound": self.bound,
            "gap": self.gap,
            "k": self.k,
            "seed": self.seed,
            "sampler": self.sampler,
            "n_candidates": self.n_candidates,
            "n_points": self.n_points,
            "coverage_fraction": self.coverage_fraction,
            "timings_s": self.timings_s,
            "versions": self.versions,
            "cameras": self.cameras,
            "instance": self.instance,
            "engine": self.engine,
            "mode": self.mode,
            "solver_stats": self.solver_stats,
            "warnings": self.warnings,
            "event_mode": self.event_mode,
            "peak_frame": self.peak_frame,
            "expected_coverage": self.expected_coverage,
            "peak_coverage": self.peak_coverage,
            "points_requested": self.points_requested,
            "options": self.options,
            **({"robust": self.robust} if self.robust is not None else {}),
        }

    def save(self, outdir: str | Path) -> None:
        """Write ``solution.json`` (and, when present, candidates.csv, points.csv, visibility.cpm) atomically."""
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        if self.candidates is not None:
            self.candidates.save(outdir / "candidates.csv")
        if self.visibility is not None:
            self.visibility.save(outdir)
        write_json_atomic(outdir / "solution.json", self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "Solution":
        """Read a ``solution.json`` (or the folder holding one)."""
        data = read_json(path, "solution.json", "solution")
        known = {f for f in cls.__dataclass_fields__ if f not in ("candidates", "visibility")}
        return cls(**{k: v for k, v in data.items() if k in known})


def camera_record(instance, candidates: CandidateSet, j: int) -> dict[str, Any]:
    """The ``cameras`` entry of ``solution.json`` for candidate column ``j``."""
    cam = instance.camera
    return {
        "candidate": int(j),
        "position": [float(x) for x in candidates.positions[j]],
        "aim": [float(x) for x in candidates.aims[j]],
        "rotation": [[float(x) for x in row] for row in candidates.rotations[j]],
        "K": [[float(x) for x in row] for row in cam.K()],
        "width": int(cam.width_px),
        "height": int(cam.height_px),
        "near_m": float(cam.near_m),
        "far_m": float(cam.far_m),
    }


def event_centres(instance) -> np.ndarray:
    """(n_frames, 3) float64 centre of what is observed in each frame.

    The weighted mean of the target's bounding-box centre (weight ``target_weight``) and the
    frame's emitter points (their weights).
    """
    out = []
    for f, frame in enumerate(instance.frames):
        c, w = [instance.target_centre(f) * frame.target_weight], frame.target_weight
        if frame.emitters is not None and len(frame.emitters):
            c.append(frame.emitters.weights @ frame.emitters.positions_m)
            w += float(frame.emitters.weights.sum())
        out.append(np.sum(c, axis=0) / w if w > 0 else instance.target_centre(f))
    return np.array(out)


def event_aims(instance, orientations: int = 1) -> np.ndarray:
    """Aim points of the candidate poses at each position.

    One orientation aims at the likelihood-weighted mean event centre. ``n > 1`` orientations aim
    at the event centres of ``n`` key frames, taken at the likelihood quantiles (i + 0.5) / n of
    the frame sequence (duplicates removed), so a moving target is followed.

    Returns
    -------
    (a, 3) float64
        ``a <= orientations`` distinct aim points.
    """
    centres = event_centres(instance)
    w = instance.frame_weights()
    if orientations <= 1 or len(centres) == 1:
        return (w @ centres)[None, :]
    cdf = np.cumsum(w)
    keys = np.searchsorted(cdf, (np.arange(orientations) + 0.5) / orientations, side="left")
    keys = np.unique(np.minimum(keys, len(centres) - 1))
    return centres[keys]


from camplace.names import EVENT_MODES  # noqa: E402  (one list of the names)


def peak_frame(instance) -> int:
    """Index of the maximum-likelihood frame (the first one on ties)."""
    return int(np.argmax([f.weight for f in instance.frames]))


def event_weights(pts, instance, event_mode: str) -> np.ndarray:
    """Row weights the solver maximises: all frames (P-weighted), or the peak frame alone (summing to 1)."""
    if event_mode == "all":
        return pts.weight
    in_peak = pts.frame == peak_frame(instance)
    w = np.where(in_peak, pts.weight, 0.0)
    s = w.sum()
    return w / s if s > 0 else w


def degenerate_warnings(matrix, weights: np.ndarray, k: int) -> list[str]:
    """Plain-language warnings for problems the solver answers trivially."""
    out = []
    live_rows = weights > 0
    if not live_rows.any():
        out.append("every point weighs 0: nothing can be gained (check the frame weights and target_weight)")
        return out
    if matrix.nnz == 0:
        out.append(
            "no candidate observes any point of the event: check the volume, camera.near_m/far_m, "
            "the occluders and [quality] (incidence limit, light)"
        )
        return out
    useful = int(np.count_nonzero(np.diff(matrix[live_rows].tocsc().indptr)))
    if useful < k:
        out.append(
            f"only {useful} candidate(s) observe anything, fewer than k = {k}: the other chosen cameras add "
            "nothing (raise --candidates or widen the volume)"
        )
    return out


def split_timings(stats: dict, prefix: str = "solver") -> tuple[dict, dict[str, float]]:
    """Separate wall-clock fields (keys starting with ``time``) from solver statistics.

    Returns the statistics without them (deterministic for a given input) and the timings as flat
    ``solver.<path>`` keys, so that ``solution.json`` is identical between runs but for ``timings_s``.
    """
    clean: dict = {}
    times: dict[str, float] = {}
    for key, value in stats.items():
        path = f"{prefix}.{key}"
        if isinstance(value, dict):
            sub, sub_t = split_timings(value, path)
            clean[key] = sub
            times.update(sub_t)
        elif str(key).startswith("time") and isinstance(value, (int, float)):
            times[path] = float(value)
        else:
            clean[key] = value
    return clean, times


def covered_rows(matrix, selected) -> np.ndarray:
    """(m,) bool: rows observed by at least one of the ``selected`` columns."""
    sel = list(selected)
    if not sel:
        return np.zeros(matrix.shape[0], dtype=bool)
    return np.asarray((matrix[:, sel] > 0).sum(axis=1)).ravel() > 0


def light_curves_csv(instance, vis: VisibilityMatrix, selected) -> str:
    """``light_curves.csv``: per chosen camera and frame, the event weight it observes.

    Columns: camera (0-based position in ``solution.json`` cameras), frame, observed_weight (sum of
    the row weights it observes in that frame; a frame's rows sum to its normalised likelihood),
    observed_fraction (observed_weight / the frame's weight), candidate (column index), time_s.
    """
    pts = vis.points
    n_frames = len(instance.frames)
    frame_total = np.bincount(pts.frame, weights=pts.weight, minlength=n_frames)
    lines = ["camera,frame,observed_weight,observed_fraction,candidate,time_s"]
    csc = vis.matrix.tocsc()
    for cam, j in enumerate(selected):
        rows = csc.indices[csc.indptr[j]:csc.indptr[j + 1]]
        seen = np.bincount(pts.frame[rows], weights=pts.weight[rows], minlength=n_frames)
        for f in range(n_frames):
            frac = seen[f] / frame_total[f] if frame_total[f] > 0 else 0.0
            lines.append(f"{cam},{f},{float(seen[f])!r},{float(frac)!r},{int(j)},{float(instance.frames[f].time_s)!r}")
    return "\n".join(lines) + "\n"


def under_ground(instance, positions: np.ndarray) -> np.ndarray:
    """(n,) bool: positions under (or inside) a ``ground = true`` occluder: a ray straight up hits it."""
    from camplace.visibility import RayScene

    ground = [o.mesh.transformed(o.pose) for o in instance.occluders if o.ground]
    if not ground or len(positions) == 0:
        return np.zeros(len(positions), dtype=bool)
    scene = RayScene(ground)
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), positions.shape)
    tri, _ = scene.first_hit(positions, up)
    return tri >= 0


def make_run_candidates(instance, sampler: str, n: int, orientations: int, seed) -> CandidateSet:
    """The candidate poses of a run: ``n`` sampled positions above any ground, each aimed ``orientations`` ways.

    Positions under the terrain are rejected; since every sampler's sequence for a larger count
    starts with the sequence for a smaller one, oversampling keeps the result independent of how
    many draws were needed.
    """
    from camplace.sampling import candidates_from_positions, sample_positions

    lo, hi = instance.volume.min_m, instance.volume.max_m
    factor = 1
    while True:
        pos = sample_positions(sampler, n * factor, lo, hi, seed=seed)
        ok = ~under_ground(instance, pos)
        if ok.sum() >= n or factor >= 256:
            break
        factor *= 4
    pos = pos[ok][:n]
    if len(pos) < n:
        raise CamplaceError(
            f"{instance.source}: volume: only {len(pos)} of {n * factor} sampled positions are above the ground "
            "(raise volume.max_m above the terrain)"
        )
    return candidates_from_positions(pos, event_aims(instance, orientations), sampler=sampler)


def stage_seeds(seed: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """Independent seed streams of a run: (candidates, points)."""
    cand_seed, point_seed = np.random.SeedSequence(seed).spawn(2)
    return cand_seed, point_seed


# Bytes a matrix row (target point) and a candidate pose cost before the matrix exists: the arrays
# kept (positions, normals, frame, weight; position, aim, rotation) and the sampling temporaries.
_ROW_BYTES = 200
_POSE_BYTES = 400


def check_input_memory(n_points: int, n_frames: int, n_poses: int = 0, memory_budget_gb: float | None = None) -> None:
    """Stop with a one-line error when the rows and candidate poses alone would not fit the budget.

    Parameters
    ----------
    n_points : int
        Surface points requested (``--points``; split over ``n_frames`` frames, rounded up).
    n_frames : int
    n_poses : int
        Candidate poses (positions x orientations).
    memory_budget_gb : float or None
        Budget in GiB (default: half the machine's memory, as the visibility stage).

    Raises
    ------
    CamplaceError
        Naming the option to lower, before anything is allocated.
    """
    from camplace.visibility.engine import available_memory_bytes

    budget = available_memory_bytes() // 2 if memory_budget_gb is None else int(memory_budget_gb * 2**30)
    rows = -(-int(n_points) // max(1, n_frames)) * max(1, n_frames)
    need = rows * _ROW_BYTES + int(n_poses) * _POSE_BYTES
    if need > budget:
        what = "--points" if rows * _ROW_BYTES >= n_poses * _POSE_BYTES else "--candidates"
        raise CamplaceError(
            f"{what}: {rows:,} points and {n_poses:,} candidate poses need about {need / 2**30:.1f} GiB before the "
            f"visibility matrix, over the {budget / 2**30:.1f} GiB budget (lower {what} or raise --memory-budget-gb)"
        )


def compute_points(instance, n_points: int | None = None, seed: int | None = None):
    """The matrix rows of a run with this seed (the same points ``run`` makes).

    Parameters
    ----------
    instance : Instance
    n_points : int or None
        Surface points (default: the instance's ``run.points``).
    seed : int or None
        Run seed (default: the instance's ``run.seed``).

    Returns
    -------
    TargetPoints
    """
    n_points = instance.defaults.points if n_points is None else int(n_points)
    seed = instance.defaults.seed if seed is None else int(seed)
    if seed < 0:
        raise CamplaceError(f"--seed: must be >= 0, got {seed}")
    if n_points < 1:
        raise CamplaceError(f"--points: must be >= 1, got {n_points}")
    check_input_memory(n_points, len(instance.frames))
    return make_target_points(instance, n_points, seed=stage_seeds(seed)[1])


def visibility_stage(
    instance,
    cands: CandidateSet,
    pts,
    *,
    reporter: Reporter | None = None,
    cache: bool = True,
    dask_address: str | None = None,
    memory_budget_gb: float | None = None,
) -> VisibilityMatrix:
    """Compute (or fetch from the cache) the visibility matrix, with a progress bar."""
    from camplace.visibility.cache import default_cache_dir

    reporter = reporter or Reporter()
    if memory_budget_gb is not None and not memory_budget_gb > 0:
        raise CamplaceError(f"--memory-budget-gb: must be > 0, got {memory_budget_gb}")
    budget = None if memory_budget_gb is None else int(memory_budget_gb * 2**30)
    with reporter.stage("visibility", total=len(cands)) as advance:
        return compute_visibility(
            instance, cands, pts, progress=advance, memory_budget_bytes=budget, dask_address=dask_address,
            cache_dir=default_cache_dir() if cache else None,
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
    event_mode : {"all", "peak"}
        ``all`` maximises the expected coverage over all frames (weights P(t)); ``peak`` places the
        cameras for the maximum-likelihood frame alone (the thesis's PS01).
    mode : {"maxcover", "quality", "multiview", "setcover"}
        The formulation (see :func:`camplace.solver.modes.solve`): the observed weight, the weight
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

    Returns
    -------
    Solution
    """
    from camplace.instance import resolve_instance, save_instance
    from camplace.solver.modes import solve

    from camplace.solver.options import SolveOptions

    if solve_options is not None:
        o = solve_options
        mode, views, min_angle_deg, fixed, forbidden = o.mode, o.views, o.min_angle_deg, o.fixed, o.forbidden
        min_distance_m, required_fraction, engine = o.min_distance_m, o.required_fraction, o.engine
        k = k if o.k is None else o.k
        time_limit_s = time_limit_s if o.time_limit_s is None else o.time_limit_s
    if not hasattr(instance, "frames"):
        instance = resolve_instance(str(instance), seed=seed)
    if event_mode not in EVENT_MODES:
        raise CamplaceError(f"--event-mode: unknown mode {event_mode!r} (use one of {', '.join(EVENT_MODES)})")
    reporter = reporter or Reporter()
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
    if time_limit_s <= 0:
        raise CamplaceError(f"--time-limit: must be > 0 seconds, got {time_limit_s}")
    if matrix_format not in ("cpm", "npz"):
        raise CamplaceError(f"--matrix-format: unknown format {matrix_format!r} (use cpm or npz)")

    check_input_memory(n_points, len(instance.frames), n_cand * orientations, memory_budget_gb)
    if memory_budget_gb is not None and not memory_budget_gb > 0:
        raise CamplaceError(f"--memory-budget-gb: must be > 0, got {memory_budget_gb}")
    solve_opts = SolveOptions(
        mode=mode, k=None if mode == "setcover" else k, views=views, min_angle_deg=min_angle_deg,
        required_fraction=required_fraction, fixed=tuple(fixed), forbidden=tuple(forbidden),
        min_distance_m=min_distance_m, engine=engine, time_limit_s=time_limit_s,
        memory_budget_bytes=None if memory_budget_gb is None else int(memory_budget_gb * 2**30),
    )
    options = {**solve_opts.record(), "event_mode": event_mode, "sampler": sampler, "seed": seed, "candidates": n_cand,
               "points": n_points, "orientations": orientations}
    robust = instance.robust if robust is None else robust
    if robust is not None:
        from camplace.robust import check_request, spec_record

        check_request(robust, mode, min_angle_deg, engine)
        options["robust"] = spec_record(robust)
    timings: dict[str, float] = {}
    cand_seed, _ = stage_seeds(seed)

    t0 = time.perf_counter()
    with reporter.stage("sampling"):
        cands = make_run_candidates(instance, sampler, n_cand, orientations, cand_seed)
        cands = CandidateSet(cands.positions, cands.aims, cands.rotations, sampler=sampler, seed=seed)
        pts = compute_points(instance, n_points, seed)
    timings["sampling"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    vis = visibility_stage(
        instance, cands, pts, reporter=reporter, cache=cache, dask_address=dask_address, memory_budget_gb=memory_budget_gb
    )
    timings["visibility"] = time.perf_counter() - t0
    timings.update(vis.timings_s)  # cache.load / cache.store (inside the visibility stage)

    peak = peak_frame(instance)
    solve_w = event_weights(pts, instance, event_mode)
    geometric = min_angle_deg is not None or min_distance_m is not None
    t0 = time.perf_counter()
    with reporter.stage("solve"):
        res = solve(vis.matrix, solve_w, positions=cands.positions if geometric else None,
                    points=pts.positions if geometric else None, options=solve_opts)
    timings["solve"] = time.perf_counter() - t0
    robust_record = None
    if robust is not None:
        from camplace.robust import robust_stage

        res, robust_record = robust_stage(
            instance, cands, pts, vis.matrix, solve_w, res, robust, options, seed=seed, cache=cache, reporter=reporter,
            memory_budget_bytes=None if memory_budget_gb is None else int(memory_budget_gb * 2**30), timings=timings,
        )
    # the system's size: the fixed cameras plus the new ones (setcover: as many as it needed)
    k = len(res.selected) if (mode == "setcover" or fixed) else k

    notes = degenerate_warnings(vis.matrix, solve_w, k)
    for note in notes:
        log.info("%s", note)
    solver_stats, solver_times = split_timings(dict(res.stats))
    timings.update(solver_times)
    total_weight = float(solve_w.sum())
    observed = covered_rows(vis.matrix, res.selected)
    in_peak = pts.frame == peak
    # no incumbent at all (a time limit before the first solution): objective 0, gap 100%
    bound = float(res.bound) if np.isfinite(res.bound) else total_weight
    gap = float(res.gap) if np.isfinite(res.gap) else 1.0
    solution = Solution(
        status=res.status,
        objective=float(res.objective),
        bound=bound,
        gap=gap,
        k=k,
        seed=seed,
        sampler=sampler,
        n_candidates=len(cands),
        n_points=len(pts),
        coverage_fraction=float(solve_w[observed].sum()) / total_weight if total_weight > 0 else 0.0,
        timings_s=timings,
        versions=versions(),
        cameras=[camera_record(instance, cands, j) for j in res.selected],
        instance=instance.name,
        engine=res.engine,
        mode=mode,
        solver_stats=solver_stats,
        warnings=notes,
        event_mode=event_mode,
        peak_frame=peak,
        expected_coverage=float(pts.weight[observed].sum() / pts.weight.sum()),
        peak_coverage=float(pts.weight[observed & in_peak].sum() / max(pts.weight[in_peak].sum(), 1e-300)),
        points_requested=n_points,
        options=options,
        robust=robust_record,
        candidates=cands,
        visibility=vis,
    )
    if outdir is not None:
        t0 = time.perf_counter()
        with reporter.stage("write"):
            outdir = Path(outdir)
            outdir.mkdir(parents=True, exist_ok=True)
            remove_stale_temps(outdir)
            write_ply(outdir / "scene.ply", frame_scene(instance, 0).triangles)
            save_instance(instance, outdir / "instance.toml", mesh_files=True)
            cands.save(outdir / "candidates.csv")
            t1 = time.perf_counter()
            vis.save_matrix(outdir, matrix_format)
            timings["write.matrix"] = time.perf_counter() - t1
            vis.points.save(outdir / "points.csv")
            write_text_atomic(outdir / "light_curves.csv", light_curves_csv(instance, vis, res.selected))
            timings["write"] = time.perf_counter() - t0
            # solution.json last: its presence means the run's outputs are complete
            write_json_atomic(outdir / "solution.json", solution.to_dict())
    return solution
