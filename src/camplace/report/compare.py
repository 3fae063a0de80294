"""A run's optimised system against campaign systems, on the same matrix rows.

The guarantee the report states: **the optimised system scores at least as well as every campaign
system on the same matrix.** Campaign cameras stand at fresh positions (not among the run's
candidates), so :func:`compare_with_campaigns` works on the *union* matrix: the run's columns
(``visibility.cpm``) side by side with every campaign's columns, all on the run's rows (a campaign is
accepted only when its :func:`~camplace.report.campaign.problem_fingerprint` equals the run's:
same instance, seed and points, and when it used the run's event mode, i.e. the same row weights). Every system is scored there with the solver's objective
(:func:`camplace.solver.coverage_weight`).

* When the run's chosen system already scores at least as well as every campaign system (within
  ``TIE = 1e-12`` of float rounding), it is the optimised system (``method = "run"``): it is proven
  optimal over the run's candidates, and no campaign system beats it.
* Otherwise (or with ``union="always"``) the k-camera problem is re-solved over the union of the
  run's candidates and all campaign cameras (``method = "union"``); a proven-optimal answer scores at
  least as well as every campaign system, because each of them is a feasible choice there.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace.errors import CamplaceError

log = logging.getLogger(__name__)

__all__ = ["RunData", "load_run_data", "Comparison", "compare_with_campaigns", "TIE"]

#: Objective differences below this are float rounding (sums of up to 1e6 weights in float64).
TIE = 1e-12


@dataclass(frozen=True, eq=False)
class RunData:
    """What the report needs from a ``camplace run`` output folder.

    Attributes
    ----------
    outdir : Path
    instance : camplace.instance.Instance
    solution : camplace.solution.Solution
    points : camplace.visibility.TargetPoints
        The rows: the run's ``points.csv``.
    weights : (n_points,) float64
        The row weights the run's solver maximised (:func:`camplace.event.event_weights` of its event mode).
    matrix : (n_points, n_candidates) scipy.sparse.csr_matrix
    candidates : camplace.sampling.CandidateSet
    fingerprint : str
        :func:`~camplace.report.campaign.problem_fingerprint` of the rows.
    """

    outdir: Path
    instance: Any
    solution: Any
    points: Any
    weights: Any
    matrix: Any
    candidates: Any
    fingerprint: str

    @property
    def aims(self) -> np.ndarray:
        """(a, 3) float64 the distinct aim points of the run's candidates, in column order."""
        a = self.candidates.aims
        n = 1
        while n < len(a) and np.allclose(self.candidates.positions[n], self.candidates.positions[0]):
            n += 1
        return a[:n].copy()


def load_run_data(outdir: str | Path) -> RunData:
    """Read a run folder (:class:`camplace.RunFolder`): instance.toml, solution.json, candidates.csv,
    points.csv and the matrix (visibility.cpm or visibility.npz).

    The rows are the run's own (``points.csv``, written with exact floats), so their number is the
    matrix's row count and ``solution.json``'s ``n_points``.

    Raises
    ------
    CamplaceError
        When a file is missing or the matrix does not match the solution's sizes.
    """
    from camplace.report.campaign import problem_fingerprint
    from camplace.runfolder import RunFolder

    run = RunFolder(outdir)
    outdir = run.path
    solution, instance = run.solution, run.instance
    run.require_cameras()
    run.check_sizes()
    matrix, points, cands = run.matrix, run.points, run.candidates
    weights = run.weights()
    return RunData(outdir, instance, solution, points, weights, matrix, cands, problem_fingerprint(instance, points))


@dataclass(frozen=True)
class Comparison:
    """The optimised system on the shared rows, and how it compares with the campaign systems.

    Attributes
    ----------
    method : {"run", "union"}
        "run": the run's system, which no campaign system beats; "union": re-solved over the
        union of the run's candidates and the campaign cameras.
    objective, bound, gap : float
        Of the optimised system (bound and gap: the proof over the candidates it was chosen from).
    status : str
        Solver status of that proof.
    cameras : list of dict
        Per camera: source ("run candidate j" or "<campaign> system s camera c"), position, aim, rotation.
    run_objective : float
        The run's system on the shared rows.
    campaign_best : dict of str to float
        Best campaign system per campaign.
    holds : bool
        ``objective >= every campaign system - TIE``.
    n_columns : int
        Columns the optimised system was chosen from.
    time_s : float
    note : str
        Why this method was used.
    """

    method: str
    objective: float
    bound: float
    gap: float
    status: str
    cameras: list = field(default_factory=list)
    run_objective: float = 0.0
    campaign_best: dict = field(default_factory=dict)
    holds: bool = True
    n_columns: int = 0
    time_s: float = 0.0
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def check_campaign(run: RunData, campaign) -> None:
    """Raise a CamplaceError unless ``campaign`` was scored on the run's rows with the run's k and objective."""
    from camplace.report.campaign import scoring_of

    where = campaign.name or campaign.sampler
    sol = run.solution
    if campaign.k != len(sol.cameras):
        raise CamplaceError(f"{where}: campaign systems have k = {campaign.k} cameras but the run chose {len(sol.cameras)} (re-run 'camplace campaign ... --k {len(sol.cameras)}')")
    mode = getattr(sol, "event_mode", "all") or "all"
    if campaign.event_mode != mode:
        raise CamplaceError(f"{where}: scored with --event-mode {campaign.event_mode} but the run used {mode} (re-run 'camplace campaign ... --event-mode {mode}')")
    want = scoring_of(sol)
    got = {"mode": campaign.mode, "views": campaign.views, "min_angle_deg": campaign.min_angle_deg}
    if got != want:
        raise CamplaceError(f"{where}: scored with {got} but the run's objective is {want} "
                            f"(re-run 'camplace campaign {run.outdir} --systems {campaign.n_systems} --sampler {campaign.sampler}')")
    if campaign.fingerprint != run.fingerprint:
        raise CamplaceError(
            f"{where}: scored on other rows than the run in {run.outdir} (campaign: {campaign.instance}, seed {campaign.seed}, "
            f"{campaign.n_points} rows; run: {sol.instance}, seed {sol.seed}, {sol.n_points} rows); re-run "
            f"'camplace campaign {run.outdir} --systems {campaign.n_systems} --sampler {campaign.sampler}'"
        )


def compare_with_campaigns(
    run: RunData,
    campaigns: Sequence,
    *,
    union: str = "auto",
    time_limit_s: float | None = None,
    engine: str = "auto",
) -> Comparison:
    """Find the optimised system and check it against every campaign system on the shared rows.

    Parameters
    ----------
    run : RunData
    campaigns : sequence of Campaign
        With their matrices loaded (``Campaign.load(..., matrix=True)``).
    union : {"auto", "always"}
        "auto" re-solves over the union only when a campaign system beats the run's system.
    time_limit_s : float or None
        Limit of that re-solve (default: the instance's run time limit).
    engine : str
        Solver engine of the re-solve.

    Returns
    -------
    Comparison
    """
    import scipy.sparse as sp

    from camplace.report.campaign import scoring_of
    from camplace.solver import solve
    from camplace.solver.problem.objectives import mode_value

    if union not in ("auto", "always"):
        raise CamplaceError(f"--union: use auto or always, got {union!r}")
    t0 = time.perf_counter()
    sol = run.solution
    w = run.weights
    for c in campaigns:
        check_campaign(run, c)
        if c.matrix is None:
            raise CamplaceError(f"{c.name}: the campaign's visibility matrix is not loaded (Campaign.load(..., matrix=True))")
    scoring = scoring_of(sol)
    angle = scoring["min_angle_deg"] is not None
    run_obj = mode_value(run.matrix, w, sol.selected, **scoring, positions=run.candidates.positions,
                         points=run.points.positions)
    best = {c.name: float(c.objective.max()) for c in campaigns}
    top = max(best.values(), default=-np.inf)

    names = [c.name for c in run.instance.cameras]
    team = getattr(run.instance, "team", None) is not None

    def cam_rec(source: str, pos, aim, rot, column, model: int | None = None) -> dict[str, Any]:
        alone = float(np.dot(w, np.asarray((column > 0).toarray()).ravel()))
        rec = {"source": source, "position": [float(x) for x in pos], "aim": [float(x) for x in aim],
               "rotation": [[float(x) for x in r] for r in rot], "observed_weight": alone}
        if team:  # the camera model of a team's camera (index into instance.cameras)
            rec["model"] = names[int(model or 0)]
            rec["model_index"] = int(model or 0)
        return rec

    # the run's proof is about its own objective; a setcover run's cameras are compared by what they observe
    proof = (float(sol.bound), float(sol.gap), sol.status) if sol.mode != "setcover" else (float(run_obj), 0.0, "feasible")
    if run_obj >= top - TIE and union == "auto":
        cams = [cam_rec(f"run candidate {c['candidate']}", c["position"], c.get("aim", c["position"]), c["rotation"],
                        run.matrix[:, int(c["candidate"])], c.get("model_index")) for c in sol.cameras]
        note = ("the run's system scores at least as well as every campaign system on the shared rows "
                "(no re-solve needed)") if campaigns else "no campaign to compare with"
        return Comparison("run", float(run_obj), *proof, cams, float(run_obj), best,
                          bool(run_obj >= top - TIE), run.matrix.shape[1], time.perf_counter() - t0, note)

    blocks = [run.matrix] + [sp.csr_matrix(c.matrix) for c in campaigns]
    U = sp.hstack(blocks, format="csr")
    limit = run.instance.defaults.time_limit_s if time_limit_s is None else float(time_limit_s)
    positions = np.concatenate([run.candidates.positions] + [c.positions.reshape(-1, 3) for c in campaigns])
    res = solve(U, w, len(sol.cameras), **scoring, positions=positions if angle else None,
                points=run.points.positions if angle else None, engine=engine, time_limit_s=limit)
    offsets = np.cumsum([0] + [b.shape[1] for b in blocks])
    cams = []
    for j in res.selected:
        b = int(np.searchsorted(offsets, j, side="right") - 1)
        local = j - offsets[b]
        if b == 0:
            cams.append(cam_rec(f"run candidate {local}", run.candidates.positions[local], run.candidates.aims[local],
                                run.candidates.rotations[local], U[:, j], int(run.candidates.models()[local])))
        else:
            c = campaigns[b - 1]
            s, cc = divmod(int(local), c.k)
            cams.append(cam_rec(f"{c.name} system {s + 1} camera {cc + 1}", c.positions[s, cc], c.aims[s, cc], c.rotations[s, cc], U[:, j],
                                None if c.model is None else int(c.model[s, cc])))
    why = "requested (--union always)" if union == "always" else f"a campaign system ({top:.6f}) beat the run's system ({run_obj:.6f})"
    note = f"re-solved over the union of the run's {run.matrix.shape[1]} candidates and {U.shape[1] - run.matrix.shape[1]} campaign cameras: {why}"
    log.info("report: %s -> %s objective %.6f", note, res.status, res.objective)
    return Comparison("union", float(res.objective), float(res.bound), float(res.gap), res.status, cams, float(run_obj), best,
                      bool(res.objective >= top - TIE), U.shape[1], time.perf_counter() - t0, note)
