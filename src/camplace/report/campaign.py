"""Campaigns: random k-camera systems scored with the solver's objective and the thesis's legacy score.

A campaign of ``N`` systems samples ``N * k`` camera positions inside the instance's volume with one
of the samplers (chaotic, uniform, sobol), aims each at the event (:func:`camplace.event.event_aims`;
with several aim points each camera gets one at random), groups them k by k into systems, and scores
each system

* with the **objective** the solver maximises: the weight of the matrix rows observed by at least one
  of its cameras (:func:`camplace.solver.coverage_weight`), on exactly the rows a ``camplace run``
  with the same ``seed`` and ``points`` uses (:func:`camplace.visibility.stages.compute_points`), weighted
  as the run's ``--event-mode`` weights them (:func:`camplace.event.event_weights`); the
  cameras' visibility columns come from the same ray caster (and cache) as a run's;
* with the thesis's **legacy** score (Algorithm 2, :mod:`camplace.report.legacy`, literal).

Positions are drawn like a run's candidates (above any ground, :func:`camplace.visibility.stages.make_run_candidates`)
but from their own seed stream, independent of a run's candidates and points:
``SeedSequence(seed).spawn(3)[2]`` (a run uses children 0 and 1), split into positions and aims.

Output folder (:meth:`Campaign.save`):

``campaign.csv``
    One row per camera: ``system, camera, x, y, z, objective, legacy_score, coverage_fraction,
    aim_x, aim_y, aim_z, camera_objective, legacy_distance_m, legacy_area, legacy_camera_score,
    column`` (systems and cameras count from 1; ``objective``, ``legacy_score`` and
    ``coverage_fraction`` are the system's, repeated on each of its rows).
``campaign.json``
    Settings, summary statistics, the legacy constants and the fingerprint of the scoring problem.
``cameras.csv``
    The poses, in the ``candidates.csv`` format (column ``s * k + c`` is camera c of system s).
``visibility.cpm``
    The rows x cameras visibility matrix (float32 CSR; :func:`camplace.load_visibility` reads it,
    ``camplace convert-matrix DIR --format npz`` turns it into a ``scipy.sparse.load_npz`` file),
    for re-solving with a run's candidates.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camplace._io import write_json_atomic, write_text_atomic
from camplace.errors import CamplaceError
from camplace.report.legacy import LegacyTarget, legacy_camera_scores, legacy_target

log = logging.getLogger(__name__)

__all__ = [
    "Campaign",
    "CAMPAIGN_COLUMNS",
    "campaign_seed",
    "campaign_for_run",
    "problem_fingerprint",
    "run_campaign",
    "score_systems",
    "scoring_of",
    "find_campaigns",
]

CAMPAIGN_COLUMNS = (
    "system", "camera", "x", "y", "z", "objective", "legacy_score", "coverage_fraction",
    "aim_x", "aim_y", "aim_z", "camera_objective", "legacy_distance_m", "legacy_area",
    "legacy_camera_score", "column",
)
FORMAT = "camplace-campaign/1"
CAMPAIGN_FILES = ("campaign.csv", "campaign.json", "cameras.csv", "visibility.cpm")  # what Campaign.save writes


def campaign_seed(seed: int) -> np.random.SeedSequence:
    """The seed stream of a campaign: child 2 of ``SeedSequence(seed)`` (a run uses children 0 and 1)."""
    return np.random.SeedSequence(int(seed)).spawn(3)[2]


def problem_fingerprint(instance, points) -> str:
    """SHA-256 of everything except the camera poses that decides a visibility matrix's values.

    The rows (positions, normals, frames, weights), the camera model, the quality settings, the
    light and every frame's occluder and target triangles. Two matrices with the same fingerprint
    have the same rows and can be put side by side (column-wise).

    Parameters
    ----------
    instance : camplace.instance.Instance
    points : camplace.visibility.TargetPoints

    Returns
    -------
    str
        64 hex digits.
    """
    h = hashlib.sha256(b"camplace-problem-1")
    for name in ("positions", "normals", "frame", "weight"):
        a = np.ascontiguousarray(getattr(points, name))
        h.update(f"{name}{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    cam = instance.camera
    h.update(repr((cam.sensor_width_mm, cam.sensor_height_mm, cam.focal_length_mm, cam.width_px, cam.height_px,
                   cam.near_m, cam.far_m)).encode())
    if getattr(instance, "team", None) is not None:  # every model (single-model fingerprints as they were)
        h.update(repr([(c.name, c.sensor_width_mm, c.sensor_height_mm, c.focal_length_mm, c.width_px, c.height_px,
                        c.near_m, c.far_m) for c in instance.cameras]).encode())
    h.update(repr(instance.quality).encode())
    h.update(repr(tuple(float(x) for x in instance.light.position_m)).encode())
    for f in range(len(instance.frames)):
        for _, v, fc in instance.occluders_world(f) + [("target", *instance.target_world(f))]:
            tri = np.ascontiguousarray(np.asarray(v, dtype=np.float64)[np.asarray(fc)])
            h.update(f"frame{f}{tri.shape}".encode())
            h.update(tri.tobytes())
    return h.hexdigest()


def scoring_of(solution) -> dict[str, Any]:
    """How a run's systems are scored: its solver mode and the options that define the objective.

    Parameters
    ----------
    solution : camplace.solution.Solution

    Returns
    -------
    dict
        ``mode`` (a setcover run is scored by the weight its cameras observe, ``maxcover``),
        ``views`` and ``min_angle_deg`` (multiview only; else 2 and None).
    """
    mode = getattr(solution, "mode", "maxcover") or "maxcover"
    opts = getattr(solution, "options", None) or {}
    if mode == "setcover":
        mode = "maxcover"
    multiview = mode == "multiview"
    return {"mode": mode, "views": int(opts.get("views") or 2) if multiview else 2,
            "min_angle_deg": opts.get("min_angle_deg") if multiview else None}


def score_systems(matrix, weights: np.ndarray, columns: np.ndarray, *, mode: str = "maxcover", views: int = 2,
                  min_angle_deg: float | None = None, positions: np.ndarray | None = None,
                  points: np.ndarray | None = None) -> np.ndarray:
    """The solver's objective for each system (:func:`camplace.solver.mode_value` of its columns).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix
    weights : (m,) float64
    columns : (n_systems, k) int
        Column indices of each system's cameras.
    mode, views, min_angle_deg : optional
        The formulation whose objective scores the systems (default maxcover: observed weight).
    positions : (n, 3) float64 or None
        Camera centres of the columns, metres (``min_angle_deg`` only).
    points : (m, 3) float64 or None
        Row positions, metres (``min_angle_deg`` only).

    Returns
    -------
    (n_systems,) float64
    """
    import scipy.sparse as sp

    from camplace.solver import coverage_weight
    from camplace.solver.problem.objectives import mode_value

    if mode == "maxcover":
        csc = sp.csc_matrix(matrix)
        return np.array([coverage_weight(csc, weights, [int(j) for j in cols]) for cols in np.atleast_2d(columns)],
                        dtype=np.float64)
    csr = sp.csr_matrix(matrix)
    return np.array([mode_value(csr, weights, [int(j) for j in cols], mode=mode, views=views, min_angle_deg=min_angle_deg,
                                positions=positions, points=points) for cols in np.atleast_2d(columns)], dtype=np.float64)


def _summary(values: np.ndarray) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    return {
        "min": float(v.min()), "p25": float(np.percentile(v, 25)), "median": float(np.median(v)),
        "mean": float(v.mean()), "p75": float(np.percentile(v, 75)), "max": float(v.max()),
    }


@dataclass(frozen=True, eq=False)
class Campaign:
    """Random k-camera systems and their scores.

    Attributes
    ----------
    instance : str
        Instance name.
    sampler : str
    seed : int
    k : int
    n_points : int
        Rows the systems were scored on (those of a run with this ``seed`` and ``points``).
    positions : (n_systems, k, 3) float64
        Camera centres, metres.
    aims : (n_systems, k, 3) float64
    rotations : (n_systems, k, 3, 3) float64
        World-from-camera, OpenCV axes.
    objective : (n_systems,) float64
        Weight of the rows observed by the system (the solver's objective).
    camera_objective : (n_systems, k) float64
        Weight of the rows each camera observes alone.
    legacy_score : (n_systems,) float64
        Sum over the system's cameras of Algorithm 2's delta.
    legacy_distance_m, legacy_area, legacy_camera_score : (n_systems, k) float64
        Algorithm 2's d, a and delta = d + a per camera.
    legacy : LegacyTarget
        The constants of Algorithm 2.
    total_weight : float
        Weight of all rows (1 for an instance's points).
    event_mode : {"all", "peak"}
        Row weights of the objective (as ``camplace run --event-mode``).
    fingerprint : str
        :func:`problem_fingerprint` of the scoring problem.
    mode, views, min_angle_deg
        The objective the systems were scored with (:func:`score_systems`; a run's :func:`scoring_of`).
    timings_s : dict
    name : str
        The folder name it was loaded from (or ``campaign-{sampler}``).
    matrix : scipy.sparse.csr_matrix or None
        (n_points, n_systems * k) visibility of the cameras, column ``s * k + c``.
    model : (n_systems, k) int16 or None
        A team's camera model of each camera (index into ``Instance.cameras``): each random camera
        stands at a sampled position with one of the models that may stand there, drawn uniformly.
    """

    instance: str
    sampler: str
    seed: int
    k: int
    n_points: int
    positions: np.ndarray
    aims: np.ndarray
    rotations: np.ndarray
    objective: np.ndarray
    camera_objective: np.ndarray
    legacy_score: np.ndarray
    legacy_distance_m: np.ndarray
    legacy_area: np.ndarray
    legacy_camera_score: np.ndarray
    legacy: LegacyTarget
    total_weight: float = 1.0
    event_mode: str = "all"
    fingerprint: str = ""
    mode: str = "maxcover"
    views: int = 2
    min_angle_deg: float | None = None
    timings_s: dict = field(default_factory=dict)
    name: str = ""
    matrix: Any = field(default=None, repr=False)
    model: np.ndarray | None = None

    @property
    def n_systems(self) -> int:
        return int(self.positions.shape[0])

    @property
    def coverage_fraction(self) -> np.ndarray:
        """(n_systems,) float64 objective / total weight."""
        return self.objective / self.total_weight if self.total_weight > 0 else np.zeros_like(self.objective)

    def candidates(self):
        """The cameras as a :class:`~camplace.sampling.CandidateSet` (column ``s * k + c``)."""
        from camplace.sampling import CandidateSet

        n = self.n_systems * self.k
        return CandidateSet(self.positions.reshape(n, 3), self.aims.reshape(n, 3), self.rotations.reshape(n, 3, 3),
                            sampler=self.sampler, seed=self.seed, model=None if self.model is None else self.model.reshape(n))

    def summary(self) -> dict[str, Any]:
        """Statistics of the objective and the legacy score, and the best system (1-based)."""
        from scipy.stats import spearmanr

        rho = None
        if self.n_systems >= 2 and np.ptp(self.objective) > 0 and np.ptp(self.legacy_score) > 0:
            rho = float(spearmanr(self.legacy_score, self.objective).statistic)
        return {
            "objective": _summary(self.objective),
            "coverage_fraction": _summary(self.coverage_fraction),
            "legacy_score": _summary(self.legacy_score),
            "best_system": int(np.argmax(self.objective)) + 1,
            "best_legacy_system": int(np.argmax(self.legacy_score)) + 1,
            "spearman_legacy_vs_objective": rho,
        }

    # ---------------------------------------------------------------------------------------------
    # files

    def to_csv(self) -> str:
        """The ``campaign.csv`` text (one row per camera; floats written exactly)."""
        buf = io.StringIO()
        buf.write(",".join(CAMPAIGN_COLUMNS) + "\n")
        for s in range(self.n_systems):
            for c in range(self.k):
                p, a = self.positions[s, c], self.aims[s, c]
                vals = [
                    p[0], p[1], p[2], self.objective[s], self.legacy_score[s], self.coverage_fraction[s],
                    a[0], a[1], a[2], self.camera_objective[s, c], self.legacy_distance_m[s, c],
                    self.legacy_area[s, c], self.legacy_camera_score[s, c],
                ]
                buf.write(f"{s + 1},{c + 1}," + ",".join(repr(float(v)) for v in vals) + f",{s * self.k + c}\n")
        return buf.getvalue()

    def to_dict(self) -> dict[str, Any]:
        """The ``campaign.json`` content."""
        from camplace.solution import versions

        return {
            "format": FORMAT,
            "instance": self.instance,
            "sampler": self.sampler,
            "seed": self.seed,
            "k": self.k,
            "n_systems": self.n_systems,
            "n_points": self.n_points,
            "total_weight": self.total_weight,
            "event_mode": self.event_mode,
            "fingerprint": self.fingerprint,
            "mode": self.mode,
            "views": self.views,
            "min_angle_deg": self.min_angle_deg,
            "objective": "the solver's objective of the mode (maxcover: weight of the rows observed by at least one "
                         "camera), on the rows of a run with the same seed and points (n_points = rows)",
            "legacy": {**self.legacy.to_dict(), "score": "sum over cameras of d + a (thesis Algorithm 2, literal)"},
            "summary": self.summary(),
            "timings_s": self.timings_s,
            "versions": versions(),
            "files": list(CAMPAIGN_FILES),
        }

    def save(self, outdir: str | Path) -> Path:
        """Write campaign.csv, cameras.csv, visibility.cpm (when the matrix is held; see
        :mod:`camplace.visibility.store`) and campaign.json atomically.

        ``campaign.json`` is written last: its presence means the campaign is complete.
        """
        from camplace.visibility.store import save_matrix

        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        write_text_atomic(outdir / "campaign.csv", self.to_csv())
        self.candidates().save(outdir / "cameras.csv")
        if self.matrix is not None:
            save_matrix(outdir, self.matrix)
        write_json_atomic(outdir / "campaign.json", self.to_dict())
        return outdir

    @classmethod
    def load(cls, outdir: str | Path, *, matrix: bool = False) -> "Campaign":
        """Read a campaign folder (``matrix=True`` also reads its matrix, visibility.cpm or visibility.npz)."""
        from camplace.sampling import CandidateSet

        outdir = Path(outdir)
        jpath = outdir / "campaign.json"
        try:
            meta = json.loads(jpath.read_text())
        except OSError as exc:
            raise CamplaceError(f"{jpath}: cannot read ({exc.strerror}; run 'camplace campaign ... -o {outdir}')") from None
        except json.JSONDecodeError as exc:
            raise CamplaceError(f"{jpath}: not valid JSON ({exc.msg}); re-run 'camplace campaign'") from None
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise CamplaceError(f"{jpath}: not a camplace campaign (format {FORMAT!r} expected); re-run 'camplace campaign'")
        k, n = int(meta["k"]), int(meta["n_systems"])
        cpath = outdir / "campaign.csv"
        try:
            rows = list(csv.DictReader(cpath.read_text().splitlines()))
        except OSError as exc:
            raise CamplaceError(f"{cpath}: cannot read ({exc.strerror}); re-run 'camplace campaign'") from None
        if len(rows) != n * k:
            raise CamplaceError(f"{cpath}: {len(rows)} rows, expected {n} systems x {k} cameras (re-run 'camplace campaign')")
        try:
            t = {c: np.array([float(r[c]) for r in rows]) for c in CAMPAIGN_COLUMNS}
        except (KeyError, TypeError, ValueError) as exc:
            raise CamplaceError(f"{cpath}: header must be {','.join(CAMPAIGN_COLUMNS)} with numbers below ({exc})") from None
        cams = CandidateSet.load(outdir / "cameras.csv")
        if len(cams) != n * k:
            raise CamplaceError(f"{outdir / 'cameras.csv'}: {len(cams)} cameras, expected {n * k} (re-run 'camplace campaign')")
        mat = None
        if matrix:
            from camplace.runfolder import RunFolder

            folder = RunFolder(outdir)  # a campaign folder holds its matrix as a run folder does
            try:
                mpath = folder.matrix_path
            except CamplaceError as exc:
                raise CamplaceError(f"{exc}; re-run 'camplace campaign'") from None
            mat = folder.matrix
            if mat.shape != (int(meta["n_points"]), n * k):
                raise CamplaceError(f"{mpath}: shape {mat.shape} does not match campaign.json (re-run 'camplace campaign')")
        def sk(a: np.ndarray) -> np.ndarray:
            return a.reshape(n, k)

        return cls(
            instance=str(meta["instance"]), sampler=str(meta["sampler"]), seed=int(meta["seed"]), k=k,
            n_points=int(meta["n_points"]),
            positions=cams.positions.reshape(n, k, 3), aims=cams.aims.reshape(n, k, 3), rotations=cams.rotations.reshape(n, k, 3, 3),
            objective=sk(t["objective"])[:, 0].copy(), camera_objective=sk(t["camera_objective"]),
            legacy_score=sk(t["legacy_score"])[:, 0].copy(), legacy_distance_m=sk(t["legacy_distance_m"]),
            legacy_area=sk(t["legacy_area"]), legacy_camera_score=sk(t["legacy_camera_score"]),
            legacy=LegacyTarget.from_dict(meta["legacy"]), total_weight=float(meta.get("total_weight", 1.0)), event_mode=str(meta.get("event_mode", "all")),
            fingerprint=str(meta.get("fingerprint", "")), mode=str(meta.get("mode", "maxcover")),
            views=int(meta.get("views", 2)), min_angle_deg=meta.get("min_angle_deg"), timings_s=dict(meta.get("timings_s", {})),
            name=outdir.name, matrix=mat, model=None if cams.model is None else cams.model.reshape(n, k),
        )


def _camera_poses(instance, sampler: str, n_cams: int, aims: np.ndarray, seed: int):
    """Positions of a run's sampler (above any ground, :func:`~camplace.visibility.stages.make_run_candidates`), each aimed at one of ``aims``."""
    from camplace.sampling import look_at
    from camplace.visibility.stages import make_run_candidates

    pos_seed, aim_seed = campaign_seed(seed).spawn(2)
    rng = np.random.default_rng(aim_seed)
    model = None
    if getattr(instance, "team", None) is not None:
        # a team: n_cams sampled positions, each with one of the models that may stand there
        from camplace.visibility.stages import team_positions

        positions, mount = team_positions(instance, sampler, n_cams, pos_seed)
        allowed = instance.team.allowed_models(positions, mount)
        pick = rng.random(n_cams) * allowed.sum(axis=1)
        model = np.minimum(np.sum(np.cumsum(allowed, axis=1) <= pick[:, None], axis=1), allowed.shape[1] - 1).astype(np.int16)
    else:
        positions = make_run_candidates(instance, sampler, n_cams, 1, pos_seed).positions.copy()
    which = rng.integers(len(aims), size=n_cams) if len(aims) > 1 else np.zeros(n_cams, dtype=np.int64)
    aim_rows = aims[which]
    same = np.linalg.norm(positions - aim_rows, axis=1) < 1e-9  # probability ~0 (as make_candidates)
    positions[same] += 1e-6
    return positions, aim_rows, look_at(positions, aim_rows), model


def run_campaign(
    instance,
    *,
    systems: int,
    sampler: str = "uniform",
    seed: int | None = None,
    points: int | None = None,
    k: int | None = None,
    orientations: int | None = None,
    aims: np.ndarray | None = None,
    legacy_omega: float = 0.0,
    event_mode: str = "all",
    outdir: str | Path | None = None,
    cache: bool = True,
    reporter=None,
    rows=None,
    mode: str = "maxcover",
    views: int = 2,
    min_angle_deg: float | None = None,
) -> Campaign:
    """Generate and score ``systems`` random k-camera systems.

    Parameters
    ----------
    instance : Instance or str
        An instance, a built-in name or an instance file.
    systems : int
        Number of systems N (>= 1).
    sampler : {"chaotic", "uniform", "sobol"}
        Sampler of the N * k camera positions inside the instance's volume.
    seed : int or None
        Seed of the positions and of the rows (default: the instance's run seed).
    points : int or None
        Surface points requested, as ``camplace run --points`` (default: the instance's run points);
        ignored when ``rows`` is given.
    k : int or None
        Cameras per system (default: the instance's k).
    orientations : int or None
        Aim points (:func:`~camplace.event.event_aims`; default: the instance's); each camera
        aims at one of them, drawn at random.
    aims : (a, 3) float64 or None
        Explicit aim points (overrides ``orientations``), e.g. those of a run's candidates.
    legacy_omega : float
        Algorithm 2's camera angle (added to its FoV as given).
    event_mode : {"all", "peak"}
        Row weights of the objective, as ``camplace run --event-mode``: every frame (likelihood
        weighted) or the maximum-likelihood frame alone.
    outdir : path or None
        When given, :meth:`Campaign.save` there.
    cache : bool
        Reuse / store the cameras' visibility matrix in the visibility cache.
    reporter : camplace._progress.Reporter or None
    rows : camplace.visibility.TargetPoints or None
        The matrix rows to score on, e.g. a run's ``points.csv`` (default: the rows of a run
        with this ``seed`` and ``points``, :func:`camplace.visibility.stages.compute_points`).
    mode, views, min_angle_deg
        The objective that scores the systems (:func:`score_systems`; default maxcover).

    Returns
    -------
    Campaign
        Deterministic for a given (instance, sampler, seed, rows, k, aims); its ``n_points`` is
        the number of rows.
    """
    from camplace._progress import Reporter
    from camplace.event import event_aims, event_weights
    from camplace.instance import resolve_instance
    from camplace.names import EVENT_MODES
    from camplace.sampling import SAMPLERS, CandidateSet
    from camplace.visibility.stages import compute_points, visibility_stage

    if not hasattr(instance, "frames"):
        instance = resolve_instance(str(instance), seed=seed)
    reporter = reporter or Reporter()
    d = instance.defaults
    seed = d.seed if seed is None else int(seed)
    if event_mode not in EVENT_MODES:
        raise CamplaceError(f"--event-mode: unknown mode {event_mode!r} (use one of {', '.join(EVENT_MODES)})")
    k = instance.k if k is None else int(k)
    n_points = d.points if points is None else int(points)
    if sampler not in SAMPLERS:
        raise CamplaceError(f"--sampler: unknown sampler {sampler!r} (use one of {', '.join(SAMPLERS)})")
    if isinstance(systems, bool) or int(systems) < 1:
        raise CamplaceError(f"--systems: must be >= 1, got {systems}")
    systems = int(systems)
    if k < 1:
        raise CamplaceError(f"--k: must be >= 1, got {k}")
    if seed < 0:
        raise CamplaceError(f"--seed: must be >= 0, got {seed}")
    if aims is None:
        orientations = d.orientations if orientations is None else int(orientations)
        if orientations < 1:
            raise CamplaceError(f"--orientations: must be >= 1, got {orientations}")
        aims = event_aims(instance, orientations)
    aims = np.atleast_2d(np.asarray(aims, dtype=np.float64))
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    with reporter.stage("sampling"):
        positions, aim_rows, rotations, model = _camera_poses(instance, sampler, systems * k, aims, seed)
        pts = compute_points(instance, n_points, seed) if rows is None else rows
        fingerprint = problem_fingerprint(instance, pts)
    timings["sampling"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cands = CandidateSet(positions, aim_rows, rotations, sampler=sampler, seed=seed, model=model)
    vis = visibility_stage(instance, cands, pts, reporter=reporter, cache=cache)
    timings["visibility"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    with reporter.stage("score"):
        weights = event_weights(pts, instance, event_mode)
        cols = np.arange(systems * k).reshape(systems, k)
        objective = score_systems(vis.matrix, weights, cols, mode=mode, views=views, min_angle_deg=min_angle_deg,
                                  positions=positions, points=pts.positions)
        pattern = (vis.matrix > 0).astype(np.float64)
        cam_obj = np.asarray(pattern.T @ weights, dtype=np.float64).reshape(systems, k)
        target = legacy_target(instance, legacy_omega)
        leg = legacy_camera_scores(positions.reshape(systems, k, 3), target)
    timings["score"] = time.perf_counter() - t0

    camp = Campaign(
        instance=instance.name, sampler=sampler, seed=seed, k=k, n_points=len(pts),
        positions=positions.reshape(systems, k, 3), aims=aim_rows.reshape(systems, k, 3),
        rotations=rotations.reshape(systems, k, 3, 3), objective=objective, camera_objective=cam_obj,
        legacy_score=leg["delta"].sum(axis=1), legacy_distance_m=leg["distance"], legacy_area=leg["area"],
        legacy_camera_score=leg["delta"], legacy=target, total_weight=float(weights.sum()), event_mode=event_mode,
        fingerprint=fingerprint, mode=mode, views=int(views), min_angle_deg=min_angle_deg, timings_s=timings, name=Path(outdir).name if outdir is not None else f"campaign-{sampler}",
        matrix=vis.matrix, model=None if model is None else model.reshape(systems, k),
    )
    if outdir is not None:
        with reporter.stage("write"):
            camp.save(outdir)
    log.info("campaign %s: %d systems, objective median %.4f max %.4f", sampler, systems, float(np.median(objective)), float(objective.max()))
    return camp


def campaign_for_run(run, *, systems: int, sampler: str = "uniform", legacy_omega: float = 0.0,
                     outdir: str | Path | None = None, cache: bool = True, reporter=None) -> Campaign:
    """A campaign comparable with a run: its instance, seed, rows, event mode, k and aim points.

    Parameters
    ----------
    run : camplace.report.compare.RunData
        The run folder's content (:func:`~camplace.report.compare.load_run_data`).
    systems, sampler, legacy_omega, cache, reporter
        As :func:`run_campaign`.
    outdir : path or None
        Campaign folder (default ``run.outdir / f"campaign-{sampler}"``).

    Returns
    -------
    Campaign
        Scored on exactly the run's rows (``points.csv``), so its fingerprint is the run's, with
        the run's objective (:func:`scoring_of`).
    """
    sol = run.solution
    outdir = Path(run.outdir) / f"campaign-{sampler}" if outdir is None else outdir
    return run_campaign(
        run.instance, systems=systems, sampler=sampler, seed=sol.seed, k=len(sol.cameras), aims=run.aims,
        legacy_omega=legacy_omega, event_mode=getattr(sol, "event_mode", "all") or "all", outdir=outdir, cache=cache,
        reporter=reporter, rows=run.points, **scoring_of(sol),
    )


def find_campaigns(outdir: str | Path) -> list[Path]:
    """Campaign folders (holding ``campaign.json``) directly inside ``outdir``, sorted by name."""
    outdir = Path(outdir)
    if not outdir.is_dir():
        return []
    return sorted(p for p in outdir.iterdir() if p.is_dir() and (p / "campaign.json").is_file())
