"""Samplers compared: the best k-camera objective against the number of candidates, and discrepancy.

For each sampler (chaotic, sobol, uniform) the study samples as many candidate positions as the
run, as the run does (:func:`camplace.visibility.stages.make_run_candidates`, the run's candidate seed stream
:func:`camplace.visibility.stages.stage_seeds` and aim points), so the run's own sampler reproduces exactly
the run's candidates (its matrix and solution are reused). Each
sampler's sequence is nested (the first n positions of a longer sequence are the n-position
sequence), so one visibility matrix per sampler serves every rung of the ladder: the solver is run
on its first ``n`` positions' columns for each ``n`` of the ladder, on the run's rows and row weights.

The discrepancy of the first ``n`` positions, mapped back to the unit cube, is
``scipy.stats.qmc.discrepancy`` with the centred L2 method ("CD"; lower is more uniform).
The study is saved as ``samplers.json`` in the run folder and reused when its settings match.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace._io import write_json_atomic
from camplace.errors import CamplaceError

log = logging.getLogger(__name__)

__all__ = ["SamplerStudy", "default_ladder", "sampler_study", "DISCREPANCY_METHOD"]

DISCREPANCY_METHOD = "CD"
FORMAT = "camplace-sampler-study/1"


def default_ladder(n_max: int, k: int) -> tuple[int, ...]:
    """Candidate-position counts: 25, 50, 100, 200, 500, 1000, ... below ``n_max``, then ``n_max`` (all >= k)."""
    steps = [25, 50, 100, 200, 500, 1000, 2000, 5000, 10000, 20000, 50000]
    return tuple(sorted({n for n in steps if k <= n < n_max} | {int(n_max)}))


@dataclass(frozen=True)
class SamplerStudy:
    """Best objective and discrepancy per sampler and number of candidate positions.

    Attributes
    ----------
    fingerprint : str
        Problem fingerprint of the rows (:func:`~camplace.report.campaign.problem_fingerprint`).
    seed, k : int
    ladder : tuple of int
        Numbers of candidate positions.
    samplers : tuple of str
    rows : list of dict
        Per (sampler, n_positions): n_candidates (columns), objective, bound, gap, status, engine,
        time_s, discrepancy, source ("solve" or "run": taken from the run's solution).
    time_limit_s : float
        Per solve.
    event_mode : str
        The run's event mode (row weights).
    aims : list of (3,) lists
        Aim points of the candidates.
    scoring : dict
        The objective solved (:func:`~camplace.report.campaign.scoring_of` of the run).
    """

    fingerprint: str
    seed: int
    k: int
    ladder: tuple
    samplers: tuple
    rows: list = field(default_factory=list)
    time_limit_s: float = 0.0
    discrepancy_method: str = DISCREPANCY_METHOD
    event_mode: str = "all"
    aims: list = field(default_factory=list)
    scoring: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, **{k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}}

    def save(self, path: str | Path) -> None:
        """Write ``samplers.json`` atomically."""
        write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "SamplerStudy":
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise CamplaceError(f"{path}: cannot read the sampler study ({exc}); delete it to recompute") from None
        if data.get("format") != FORMAT:
            raise CamplaceError(f"{path}: not a sampler study (format {FORMAT!r}); delete it to recompute")
        return cls(
            fingerprint=data["fingerprint"], seed=int(data["seed"]), k=int(data["k"]), ladder=tuple(data["ladder"]),
            samplers=tuple(data["samplers"]), rows=list(data["rows"]), time_limit_s=float(data["time_limit_s"]),
            discrepancy_method=str(data.get("discrepancy_method", DISCREPANCY_METHOD)),
            event_mode=str(data.get("event_mode", "all")), aims=[list(map(float, a)) for a in data.get("aims", [])],
            scoring=dict(data.get("scoring", {})),
        )

    def matches(self, fingerprint: str, seed: int, k: int, ladder: Sequence[int], samplers: Sequence[str],
                event_mode: str = "all", aims: Sequence[Sequence[float]] | None = None,
                scoring: dict | None = None) -> bool:
        """True when this study was made with these settings."""
        same_aims = aims is None or np.array_equal(np.asarray(self.aims, dtype=np.float64).reshape(-1, 3),
                                                   np.asarray(aims, dtype=np.float64).reshape(-1, 3))
        return (self.fingerprint == fingerprint and self.seed == seed and self.k == k and same_aims
                and tuple(self.ladder) == tuple(ladder) and tuple(self.samplers) == tuple(samplers)
                and self.event_mode == event_mode and (scoring is None or self.scoring == scoring))

    def series(self, sampler: str, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(n_positions, values of ``key``) of one sampler, in ladder order."""
        rows = sorted((r for r in self.rows if r["sampler"] == sampler), key=lambda r: r["n_positions"])
        return (np.array([r["n_positions"] for r in rows], dtype=np.int64),
                np.array([np.nan if r[key] is None else r[key] for r in rows], dtype=np.float64))


def sampler_study(
    run,
    *,
    samplers: Sequence[str] = ("chaotic", "sobol", "uniform"),
    ladder: Sequence[int] | None = None,
    time_limit_s: float | None = None,
    cache: bool = True,
    reporter=None,
) -> SamplerStudy:
    """Run the sampler study on a run's rows (see the module docstring).

    Parameters
    ----------
    run : camplace.report.compare.RunData
    samplers : sequence of str
    ladder : sequence of int or None
        Numbers of candidate positions (default :func:`default_ladder` up to the run's).
    time_limit_s : float or None
        Per solve (default: the instance's run time limit, at most 20 s).
    cache : bool
        Use the visibility cache for the samplers' matrices.
    reporter : Reporter or None

    Returns
    -------
    SamplerStudy
    """
    from scipy.stats import qmc

    from camplace._progress import Reporter
    from camplace.visibility.stages import make_run_candidates, stage_seeds, visibility_stage
    from camplace.sampling import SAMPLERS
    from camplace.report.campaign import scoring_of
    from camplace.solver import solve

    reporter = reporter or Reporter()
    sol, inst = run.solution, run.instance
    if getattr(inst, "team", None) is not None:
        raise CamplaceError(f"{inst.source}: the sampler study's candidate ladders are not defined for a camera team "
                            "([[cameras]] pose x model columns) yet; run it on a single-model instance")
    k = len(sol.cameras)
    aims = run.aims
    a = len(aims)
    n_max = sol.n_candidates // a
    ladder = tuple(int(n) for n in (ladder if ladder is not None else default_ladder(n_max, k)))
    for s in samplers:
        if s not in SAMPLERS:
            raise CamplaceError(f"--samplers: unknown sampler {s!r} (use {', '.join(SAMPLERS)})")
    for n in ladder:
        if not (n * a >= k and n <= n_max):
            raise CamplaceError(f"--ladder: {n} positions is outside {max(1, -(-k // a))}..{n_max} (the run has {n_max} positions)")
    limit = min(inst.defaults.time_limit_s, 20.0) if time_limit_s is None else float(time_limit_s)
    lo = np.asarray(inst.volume.min_m, dtype=np.float64)
    hi = np.asarray(inst.volume.max_m, dtype=np.float64)
    rows = []
    scoring = scoring_of(sol)
    cand_seed = stage_seeds(sol.seed)[0]
    top = max(ladder)
    for s in samplers:
        t0 = time.perf_counter()
        cands = make_run_candidates(inst, s, top, a, cand_seed)
        same_as_run = (s == sol.sampler and len(cands) <= len(run.candidates)
                       and np.array_equal(cands.positions, run.candidates.positions[: len(cands)]))
        if same_as_run:
            matrix = run.matrix[:, : len(cands)]
        else:
            cands = cands.with_run(s, sol.seed)
            matrix = visibility_stage(inst, cands, run.points, reporter=reporter, cache=cache).matrix
        log.info("sampler study: %s matrix in %.2f s (%s)", s, time.perf_counter() - t0, "run's" if same_as_run else "ray cast")
        unit = np.clip((cands.positions[::a] - lo) / (hi - lo), 0.0, 1.0)
        with reporter.stage(f"solve {s}", total=len(ladder)) as advance:
            for n in ladder:
                disc = float(qmc.discrepancy(unit[:n], method=DISCREPANCY_METHOD)) if n >= 2 else None
                if same_as_run and n * a == sol.n_candidates and scoring["mode"] == sol.mode:
                    rows.append({"sampler": s, "n_positions": n, "n_candidates": n * a, "objective": sol.objective,
                                 "bound": sol.bound, "gap": sol.gap, "status": sol.status, "engine": sol.engine,
                                 "time_s": float(sol.timings_s.get("solve", 0.0)), "discrepancy": disc, "source": "run"})
                else:
                    angle = scoring["min_angle_deg"] is not None
                    res = solve(matrix[:, : n * a], run.weights, k, **scoring, time_limit_s=limit,
                                positions=cands.positions[: n * a] if angle else None,
                                points=run.points.positions if angle else None)
                    rows.append({"sampler": s, "n_positions": n, "n_candidates": n * a, "objective": res.objective,
                                 "bound": res.bound if np.isfinite(res.bound) else None,
                                 "gap": res.gap if np.isfinite(res.gap) else None, "status": res.status,
                                 "engine": res.engine, "time_s": res.time_s, "discrepancy": disc, "source": "solve"})
                advance(1)
    mode = getattr(sol, "event_mode", "all") or "all"
    return SamplerStudy(run.fingerprint, int(sol.seed), k, ladder, tuple(samplers), rows, limit,
                        event_mode=mode, aims=[[float(x) for x in a] for a in aims], scoring=scoring)
