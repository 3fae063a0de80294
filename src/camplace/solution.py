"""The answer of a run: :class:`Solution` (the content of ``solution.json``) and its records.

Imports only numpy and the package's file helpers, so reading a run folder loads no geometry.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camplace._io import read_json, write_json_atomic

if TYPE_CHECKING:  # pragma: no cover
    from camplace.sampling import CandidateSet
    from camplace.visibility.engine import VisibilityMatrix


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
        world-from-camera, OpenCV axes), K (3x3), width, height, near_m, far_m; for a team also
        model (its name), model_index, cost and zones (the names of the zones it stands in).
    team : dict or None
        A team run (``Instance.team``): the models' costs and counts, the budget, the zones,
        ``enforced`` (true: the solver imposed the counts, the budget, the quotas and one camera
        per pose, in every mode, ``cardinality`` says whether k or the budget set the number of
        cameras; false: the robust placement, which chose among all pose x model columns) and what the chosen team
        ``uses`` of each.
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
        Things worth a look, one line each: what reading the instance warned about (an open target
        mesh, a target larger than the camera volume, dropped degenerate triangles), ``--mode quality``
        on a binary-quality instance (the same objective as maxcover), and degenerate situations
        (nothing observable, fewer useful candidates than k, all weights zero).
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
    light_curves : (k, n_frames) float64 or None
        Per chosen camera and frame, the weight it observes (``light_curves.csv``; read in the same
        pass over the matrix as the coverage figures, :func:`camplace.visibility.summary.summarise`).
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
    team: dict | None = None
    candidates: CandidateSet | None = field(default=None, repr=False)
    visibility: VisibilityMatrix | None = field(default=None, repr=False)
    light_curves: Any = field(default=None, repr=False)

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
            **({"team": self.team} if self.team is not None else {}),
        }

    def save(self, outdir: str | Path) -> None:
        """Write ``solution.json`` (and, when present, candidates.csv, points.csv, visibility.cpm) atomically.

        A whole run folder (instance, scene, light curves) is :func:`camplace.pipeline.write_stage`;
        reading one back is :class:`camplace.RunFolder`.
        """
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
        return cls.from_dict(read_json(path, "solution.json", "solution"))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Solution":
        """The Solution of a ``solution.json`` record (unknown keys ignored)."""
        known = {f for f in cls.__dataclass_fields__ if f not in ("candidates", "visibility")}
        return cls(**{k: v for k, v in data.items() if k in known})


def camera_record(instance, candidates: CandidateSet, j: int) -> dict[str, Any]:
    """The ``cameras`` entry of ``solution.json`` for candidate column ``j``.

    For a team (``instance.team``) the record also names the camera ``model`` and carries that
    model's intrinsics and ``cost``; a single-model instance's records are as they always were.
    """
    team = getattr(instance, "team", None)
    model = 0 if candidates.model is None else int(candidates.model[j])
    cam = instance.cameras[model] if team is not None else instance.camera
    extra: dict[str, Any] = {}
    if team is not None:
        extra = {"model": cam.name, "model_index": model, "cost": float(cam.cost)}
        if candidates.zones is not None and len(team.zones):
            extra["zones"] = [z.name for z, inside in zip(team.zones, candidates.zones[j]) if inside]
    return {
        **extra,
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


def team_record(instance, cameras: list[dict], *, enforced: bool = False, cardinality: str | None = None,
                why_not: str | None = None) -> tuple[dict | None, list[str]]:
    """The ``team`` entry of ``solution.json`` and the warnings of a team run (None, [] without a team).

    With ``enforced`` (the solver imposed the per-model counts, the budget, the zone quotas and
    one camera per pose: :class:`camplace.solver.problem.team.TeamConstraints`) the record says
    ``"enforced": true`` and its ``cardinality`` (``exact``: k cameras; ``budget``: any number
    within the budget); every mode of :data:`camplace.names.TEAM_MODES` (maxcover, quality,
    multiview, setcover) does. Otherwise (the robust placement, or a mode that cannot enforce
    them) they are only checked on the chosen cameras: ``"enforced": false`` and a warning names
    the ones the chosen team breaks (or says that none is enforced when it happens to meet them;
    ``why_not`` replaces the reason given). ``uses`` and ``broken`` either way.
    """
    team = getattr(instance, "team", None)
    if team is None:
        return None, []
    rec = team.record()
    counts = {m.name: 0 for m in team.models}
    zone_counts = {z.name: 0 for z in team.zones}
    for c in cameras:
        counts[c["model"]] += 1
        for z in c.get("zones", []):
            zone_counts[z] += 1
    cost = float(sum(c["cost"] for c in cameras))
    broken = []
    for m in team.models:
        if counts[m.name] < m.min_count or (m.max_count is not None and counts[m.name] > m.max_count):
            hi = "" if m.max_count is None else f"..{m.max_count}"
            broken.append(f"{counts[m.name]} {m.name} camera(s) (asked {m.min_count}{hi if hi else '+'})")
    if team.budget is not None and cost > team.budget:
        broken.append(f"cost {cost:g} over the budget {team.budget:g}")
    for z in team.zones:
        n = zone_counts[z.name]
        if n < z.min_cameras or (z.max_cameras is not None and n > z.max_cameras):
            hi = "" if z.max_cameras is None else f"..{z.max_cameras}"
            broken.append(f"{n} camera(s) in zone {z.name} (asked {z.min_cameras}{hi if hi else '+'})")
    rec.update({"enforced": bool(enforced), "uses": {"models": counts, "cost": cost, "zones": zone_counts},
                "broken": broken})
    if enforced:
        rec["cardinality"] = cardinality
        if len({(tuple(c["position"]), tuple(map(tuple, c["rotation"]))) for c in cameras}) < len(cameras):
            broken.append("two cameras share a pose")
        # the solver checked every constraint; anything broken here is a bug worth saying loudly
        return rec, ([f"team: the solver enforced the constraints but the chosen team breaks {'; '.join(broken)}"]
                     if broken else [])
    from camplace.names import TEAM_MODES

    note = ("team: the per-model counts, the budget and the zone quotas are not enforced "
            + (why_not or f"in this mode (the solver enforces them in {', '.join(TEAM_MODES)}; it chose the best k "
               "cameras over all pose x model columns)"))
    note += ": the chosen team breaks " + "; ".join(broken) if broken else "; the chosen team happens to meet them"
    return rec, [note]


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
