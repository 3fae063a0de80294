"""The robust stage: scenario matrices, the robust solve and the out-of-sample check (see
:mod:`camplace.robust`)."""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, replace
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.instance.schema import RobustSpec
from camplace.names import ROBUST_OBJECTIVES
from camplace.robust.p10 import order_p10, scenario_values
from camplace.sampling import CandidateSet
from camplace.sampling.perturb import IN_SAMPLE_STREAM, OUT_OF_SAMPLE_STREAM, perturb_poses
from camplace.solver.options import SolveOptions
from camplace.solver.result import relative_gap

__all__ = [
    "ROBUST_MODES", "make_spec", "spec_record", "stack_scenarios", "scenario_matrix", "solve_robust",
    "out_of_sample", "robust_stage", "order_p10", "scenario_values", "stack_bit_scenarios", "stack_bits_bytes",
]

log = logging.getLogger(__name__)

#: Formulations a robust run supports (setcover minimises cameras; there is nothing to average).
ROBUST_MODES = ("maxcover", "quality", "multiview")
_STACK_BYTES_PER_NNZ = 26  # the wide matrix as built (10), its key (8) and the stacked copy (8)


def make_spec(
    base: RobustSpec | None,
    pose_error: str | None = None,
    scenarios: int | None = None,
    objective: str | None = None,
) -> RobustSpec | None:
    """The robust settings of a run: the instance's ``[robust]`` table overridden by the options.

    Parameters
    ----------
    base : RobustSpec or None
        The instance's table (None when it has none).
    pose_error : str or None
        ``--pose-error POS_M,ROT_DEG``.
    scenarios : int or None
        ``--scenarios``.
    objective : str or None
        ``--robust-objective``.

    Returns
    -------
    RobustSpec or None
        None when neither the instance nor ``--pose-error`` asks for a robust run.
    """
    spec = base
    if pose_error is not None:
        parts = [p.strip() for p in str(pose_error).split(",")]
        try:
            pos, rot = (float(parts[0]), float(parts[1])) if len(parts) == 2 else (math.nan, math.nan)
        except ValueError:
            pos = rot = math.nan
        if not (math.isfinite(pos) and math.isfinite(rot)):
            raise CamplaceError(f"--pose-error: expected POS_M,ROT_DEG such as 0.1,5, got {pose_error!r}")
        if pos < 0 or rot < 0:
            raise CamplaceError(f"--pose-error: sigmas must be >= 0, got {pose_error!r}")
        if rot > 90:
            raise CamplaceError(f"--pose-error: rotation sigma must be <= 90 degrees, got {rot:g}")
        spec = replace(spec or RobustSpec(), position_sigma_m=pos, rotation_sigma_deg=rot)
    if spec is None:
        if scenarios is not None or objective is not None:
            raise CamplaceError("--scenarios/--robust-objective: need --pose-error POS_M,ROT_DEG (or a [robust] table in the instance)")
        return None
    if scenarios is not None:
        if not 1 <= int(scenarios) <= 4096:
            raise CamplaceError(f"--scenarios: must be between 1 and 4096, got {scenarios}")
        spec = replace(spec, scenarios=int(scenarios))
    if objective is not None:
        if objective not in ROBUST_OBJECTIVES:
            raise CamplaceError(f"--robust-objective: unknown objective {objective!r} (use one of {', '.join(ROBUST_OBJECTIVES)})")
        spec = replace(spec, objective=objective)
    return spec


def spec_record(spec: RobustSpec | None) -> dict[str, Any] | None:
    """JSON-ready settings (``solution.json`` ``options.robust`` and ``robust.settings``)."""
    return None if spec is None else {k: (float(v) if isinstance(v, float) else v) for k, v in asdict(spec).items()}


def check_request(spec: RobustSpec, mode: str, min_angle_deg: float | None, engine: str = "auto") -> None:
    """One-line errors for robust requests this version cannot serve."""
    if spec.objective == "p10" and engine not in ("auto", "mip") and not spec.zero:
        raise CamplaceError(f"--robust-objective p10: engine {engine} does not apply (the p10 model runs on SCIP: use --engine auto or mip)")
    if mode not in ROBUST_MODES:
        raise CamplaceError(f"--pose-error: mode {mode} is not supported (robust runs use {', '.join(ROBUST_MODES)})")
    if min_angle_deg is not None and not spec.zero:
        raise CamplaceError("--pose-error: --min-angle is not supported with a pose error yet (drop one of them)")
    if spec.objective == "p10" and mode == "quality":
        raise CamplaceError("--robust-objective p10: mode quality is not supported (use maxcover or multiview, or objective mean)")


def stack_scenarios(matrix: sp.spmatrix, n: int, scenarios: int) -> sp.csr_matrix:
    """Restack scenario column blocks into row blocks.

    Parameters
    ----------
    matrix : (m, S * n) scipy.sparse matrix (CSR is used as it is)
        Column ``s * n + j``: candidate ``j`` installed as in scenario ``s``.
    n : int
        Candidates.
    scenarios : int
        S.

    Returns
    -------
    (S * m, n) scipy.sparse.csr_matrix
        Row ``s * m + i``, column ``j`` holds ``matrix[i, s * n + j]`` (same dtype).

    Notes
    -----
    Index arithmetic on the sparse entries, nothing dense: in a canonical CSR row the entries of
    scenario ``s`` (columns ``s * n .. s * n + n - 1``) are one contiguous run, found for every row
    at once by a binary search on the global key ``row * S * n + column``; the output is then
    gathered scenario by scenario. Peak extra memory: about 16 bytes an entry (the key, then
    the output) plus 16 bytes an entry of one scenario.
    """
    a = matrix.tocsr() if matrix.format != "csr" else matrix
    if not a.has_canonical_format:
        a = a.copy()
        a.sum_duplicates()
    m = a.shape[0]
    S = int(scenarios)
    if a.shape[1] != n * S:
        raise CamplaceError(f"matrix has {a.shape[1]} columns, expected {S} x {n}")
    width = np.int64(n) * S
    key = np.repeat(np.arange(m, dtype=np.int64) * width, np.diff(a.indptr))
    key += a.indices
    starts = np.arange(m, dtype=np.int64)[:, None] * width + np.arange(S + 1, dtype=np.int64)[None, :] * n
    bounds = np.searchsorted(key, starts)  # (m, S + 1): run of scenario s in row i = bounds[i, s]:bounds[i, s + 1]
    del key, starts
    counts = np.diff(bounds, axis=1)  # (m, S)
    indptr = np.zeros(S * m + 1, dtype=np.int64)
    np.cumsum(counts.T.ravel(), out=indptr[1:])
    data = np.empty(a.nnz, dtype=a.data.dtype)
    index_type = np.int32 if n < 2**31 else np.int64
    indices = np.empty(a.nnz, dtype=index_type)
    for s in range(S):
        lo, hi = int(indptr[s * m]), int(indptr[(s + 1) * m])
        gather = np.repeat(bounds[:, s] - indptr[s * m:(s + 1) * m], counts[:, s])
        gather += np.arange(lo, hi, dtype=np.int64)
        data[lo:hi] = a.data[gather]
        indices[lo:hi] = a.indices[gather] - s * n
    if indptr[-1] < 2**31:
        indptr = indptr.astype(np.int32)
    return sp.csr_matrix((data, indices, indptr), shape=(S * m, n))


#: :func:`stack_bit_scenarios` restacks about this many bytes of unpacked bits at a time.
_STACK_BLOCK_BYTES = 64 * 2**20


def stack_bits_bytes(m: int, n: int, scenarios: int) -> int:
    """Bytes of a binary run's scenario bits: the wide (m, S * n) column bitsets as the
    visibility stage makes them, the stacked (S * m, n) ones and :func:`stack_bit_scenarios`'s
    block of unpacked bits (``_STACK_BLOCK_BYTES``)."""
    from camplace.visibility.bits import bit_words

    s = int(scenarios)
    return 8 * (n * s * bit_words(m) + n * bit_words(s * m)) + 2 * _STACK_BLOCK_BYTES


def stack_bit_scenarios(wide: Any, n: int, scenarios: int) -> Any:
    """:func:`stack_scenarios` of a binary matrix held as column bitsets, without a CSR.

    Parameters
    ----------
    wide : camplace.visibility.bits.BitMatrix
        (m, S * n): column ``s * n + j`` is candidate ``j`` installed as in scenario ``s``.
    n : int
        Candidates.
    scenarios : int
        S.

    Returns
    -------
    camplace.visibility.bits.BitMatrix
        (S * m, n): column ``j``'s rows ``s * m .. s * m + m - 1`` are the bits of wide column
        ``s * n + j`` (``(n, ceil(S * m / 64))`` uint64 words, ``8 n ceil(S m / 64)`` bytes).

    Notes
    -----
    Scenario ``s``'s rows start at bit ``s * m``, not at a word boundary unless 64 divides m: the
    columns are unpacked to bytes and packed again, a block of columns at a time (about
    ``_STACK_BLOCK_BYTES`` of bytes, in :func:`stack_bits_bytes`).
    """
    from camplace.visibility.bits import BitMatrix, bit_words

    m = wide.shape[0]
    s_count = int(scenarios)
    if wide.shape[1] != n * s_count:
        raise CamplaceError(f"matrix has {wide.shape[1]} columns, expected {s_count} x {n}")
    words_in = np.asarray(wide.words)
    out = np.zeros((n, bit_words(s_count * m)), dtype=np.uint64)
    step = max(1, _STACK_BLOCK_BYTES // max(1, s_count * m))
    cells = np.zeros((min(step, max(n, 1)), out.shape[1] * 64), dtype=np.uint8)  # rows past S * m stay 0
    for j0 in range(0, n, step):
        j1 = min(n, j0 + step)
        for s in range(s_count):
            block = words_in[s * n + j0:s * n + j1].view(np.uint8)
            cells[:j1 - j0, s * m:(s + 1) * m] = np.unpackbits(block, axis=1, count=m, bitorder="little")
        out[j0:j1] = np.packbits(cells[:j1 - j0], axis=1, bitorder="little").view(np.uint64)
    return BitMatrix(out, s_count * m)


def _compute(instance, poses: CandidateSet, pts, *, bits: bool, cache: bool, memory_budget_bytes: int | None, reporter,
             label: str):
    """The visibility of ``poses``: with ``bits``, a binary instance's column bitsets
    (:class:`~camplace.visibility.bits.BitMatrix`), else the CSR matrix."""
    from camplace.visibility import compute_visibility
    from camplace.visibility.cache import default_cache_dir

    if reporter is None:
        vis = compute_visibility(instance, poses, pts, memory_budget_bytes=memory_budget_bytes,
                                 cache_dir=default_cache_dir() if cache else None)
    else:
        with reporter.stage(label, total=len(poses)) as advance:
            vis = compute_visibility(instance, poses, pts, progress=advance, memory_budget_bytes=memory_budget_bytes,
                                     cache_dir=default_cache_dir() if cache else None)
    return vis.bits if bits and vis.bits is not None else vis.matrix


def scenario_matrix(
    instance, cands: CandidateSet, pts, spec: RobustSpec, *, seed: int, stream: int = IN_SAMPLE_STREAM,
    columns: Sequence[int] | None = None, scenarios: int | None = None, nominal_nnz: int | None = None,
    cache: bool = True, memory_budget_bytes: int | None = None, reporter=None, bits: bool = False,
) -> Any:
    """The stacked scenario matrix of some candidates (one visibility pass over S * c poses).

    Parameters
    ----------
    instance, cands, pts
        The run's instance, nominal candidates and points (rows).
    spec : RobustSpec
    seed, stream : int
        Scenario draws (:func:`camplace.sampling.perturb.pose_draws`): the in-sample stream as a
        scrambled Sobol design per candidate, any other as independent draws.
    columns : sequence of int or None
        Candidates to perturb (None: all); column t of the result is ``columns[t]``.
    scenarios : int or None
        S (default ``spec.scenarios``).
    nominal_nnz : int or None
        Entries of the nominal matrix of these columns: with it the memory is estimated before any
        ray is cast and an oversized request stops with a one-line error.
    cache, memory_budget_bytes, reporter
        As for the visibility stage.
    bits : bool
        Return a binary instance's scenarios as column bitsets (the robust stage does): no CSR is
        made. False (default): CSR float32 always.

    Returns
    -------
    (S * m, c) camplace.visibility.bits.BitMatrix, or scipy.sparse.csr_matrix of float32
        With ``bits``, a binary instance's scenarios as column bitsets (:func:`stack_bit_scenarios`:
        no CSR is made; ``nominal_nnz`` then checks :func:`stack_bits_bytes` against the budget);
        otherwise CSR values (:func:`stack_scenarios`).
    """
    from camplace.visibility.engine import available_memory_bytes

    s_count = int(spec.scenarios if scenarios is None else scenarios)
    c = len(cands) if columns is None else len(columns)
    budget = memory_budget_bytes if memory_budget_bytes is not None else available_memory_bytes() // 2
    binary = bits and instance.quality.mode != "graded"  # the visibility stage makes column bitsets
    if nominal_nnz is not None:
        need = stack_bits_bytes(len(pts), c, s_count) if binary else int(nominal_nnz) * s_count * _STACK_BYTES_PER_NNZ
        if need > budget:
            raise CamplaceError(
                f"--scenarios: the {s_count} scenarios of {c} candidates need about {need / 2**30:.1f} GiB "
                f"(budget {budget / 2**30:.1f} GiB); lower --scenarios, --candidates or --points, or raise --memory-budget-gb"
            )
    poses = perturb_poses(cands, columns, s_count, spec.position_sigma_m, spec.rotation_sigma_deg, seed=seed, stream=stream,
                          design="sobol" if stream == IN_SAMPLE_STREAM else "iid")
    wide = _compute(instance, poses, pts, bits=binary, cache=cache, memory_budget_bytes=budget, reporter=reporter,
                    label="robust visibility" if stream == IN_SAMPLE_STREAM else "out-of-sample visibility")
    if getattr(wide, "format", None) == "bits":
        return stack_bit_scenarios(wide, c, s_count)
    return stack_scenarios(wide, c, s_count)


def solve_robust(
    stacked: sp.csr_matrix, weights: np.ndarray, spec: RobustSpec, options: SolveOptions, *,
    positions: np.ndarray | None = None, points: np.ndarray | None = None, incumbents: Sequence[Sequence[int]] = (),
):
    """Solve the robust objective on a stacked scenario matrix.

    Parameters
    ----------
    stacked : (S * m, n) scipy.sparse.csr_matrix or camplace.visibility.bits.BitMatrix
        Scenario-stacked observations (:func:`scenario_matrix`). Bits: the mean solve reads
        them (:func:`camplace.solver.solve`'s bits route), and so does ``p10``
        (:func:`camplace.robust.p10.solve_p10`: no CSR of the stacked matrix).
    weights : (m,) float64
        The run's row weights (one scenario).
    spec : RobustSpec
    options : SolveOptions
        The run's solver options, as the nominal solve got them (mode, k, views, fixed, forbidden,
        min_distance_m, engine, time_limit_s and the memory budget, which every solve and model
        here keeps to).
    positions : (n, 3) float64 or None
        Nominal camera positions (for ``min_distance_m``, and with ``points`` for multiview with
        fixed cameras: the angle engine at 0 degrees, :func:`camplace.solver.api._fixed_views_as_angle`).
    points : (m, 3) float64 or None
        The target points (one scenario's rows), for that route.
    incumbents : sequence of systems
        Starting systems for ``p10`` (e.g. the nominal optimum).

    Returns
    -------
    camplace.solver.SolverResult
        ``mean``: the objective is the sampled expected objective (weights ``w / S`` on the
        stacked rows); ``p10``: the sampled 10th percentile.
    """
    from camplace.solver.api import solve
    from camplace.solver.problem.checks import conflict_pairs

    s_count = spec.scenarios
    min_d = options.min_distance_m
    w_stacked = np.tile(np.asarray(weights, dtype=np.float64), s_count) / s_count
    geometry = options.reads_geometry and positions is not None and points is not None
    mean = solve(stacked, w_stacked, positions=positions if min_d is not None or geometry else None,
                 points=np.tile(np.asarray(points, dtype=np.float64), (s_count, 1)) if geometry else None,
                 options=options)
    mean = _at_least_the_incumbents(mean, stacked, weights, s_count, options, incumbents)
    if spec.objective == "mean":
        return mean
    from camplace.robust.p10 import solve_p10

    conflicts = conflict_pairs(np.asarray(positions), float(min_d)) if min_d is not None else None
    # the options unchanged: the per-scenario solves and the p10 model keep to their memory budget
    # and thread count (the engine was checked by robust_checks: auto or mip)
    return solve_p10(stacked, weights, s_count, options, conflicts=conflicts, incumbents=[mean.selected, *incumbents],
                     mean_bound=mean.bound)


def _at_least_the_incumbents(mean, stacked: Any, weights: np.ndarray, s_count: int, options: SolveOptions,
                             incumbents: Sequence[Sequence[int]]):
    """The mean solve's answer, or the best of ``incumbents`` (systems that keep the same
    constraints, e.g. the nominal optimum) when the solve stopped at its time limit on a worse
    one: a robust answer is never below the nominal one's sampled mean. The bound is the solve's
    (still valid); the status is then ``feasible`` and ``stats["kept_incumbent"]`` says so."""
    best, best_value = None, float(mean.objective) if mean.selected else -math.inf
    for sel in incumbents:
        sel = tuple(sorted(int(j) for j in sel))
        if not sel:
            continue
        value = float(np.mean(scenario_values(stacked, weights, s_count, sel, mode=options.mode, views=options.views)))
        if value > best_value * (1.0 + 1e-12) + 1e-15:  # summed in another order: a relative margin
            best, best_value = sel, value
    if best is None:
        return mean
    status = "feasible" if mean.status in ("optimal", "feasible", "unknown") else mean.status
    bound = max(float(mean.bound), best_value)
    gap = relative_gap(bound, best_value)  # (inf without a finite bound, not nan)
    stats = {**mean.stats, "kept_incumbent": {"selected": list(best), "mean": best_value,
                                              "solve_objective": float(mean.objective)}}
    log.info("robust: the mean solve stopped at %.6f, below a starting system's %.6f: keeping that one",
             float(mean.objective), best_value)
    return replace(mean, selected=best, status=status, objective=best_value, bound=bound, gap=gap,
                               stats=stats)


def out_of_sample(
    instance, cands: CandidateSet, pts, weights: np.ndarray, systems: dict[str, Sequence[int]], spec: RobustSpec, *,
    seed: int, mode: str, views: int = 2, cache: bool = True, memory_budget_bytes: int | None = None, reporter=None,
) -> dict[str, np.ndarray]:
    """Per-scenario objective of some systems on ``spec.eval_scenarios`` fresh installations.

    Only the systems' cameras are perturbed (stream
    :data:`~camplace.sampling.perturb.OUT_OF_SAMPLE_STREAM`); a camera in two systems has the same
    installation in both.

    Returns
    -------
    dict of str to (S_eval,) float64
    """
    union = sorted({int(j) for sel in systems.values() for j in sel})
    stacked = scenario_matrix(
        instance, cands, pts, spec, seed=seed, stream=OUT_OF_SAMPLE_STREAM, columns=union,
        scenarios=spec.eval_scenarios, cache=cache, memory_budget_bytes=memory_budget_bytes, reporter=reporter,
        bits=True,
    )
    where = {j: t for t, j in enumerate(union)}
    return {
        name: scenario_values(stacked, weights, spec.eval_scenarios, [where[int(j)] for j in sel], mode=mode, views=views)
        for name, sel in systems.items()
    }


def _summary(values: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(values)), "p10": order_p10(values), "min": float(np.min(values)), "max": float(np.max(values))}


def robust_stage(
    instance, cands: CandidateSet, pts, nominal_matrix: sp.csr_matrix, weights: np.ndarray, nominal, spec: RobustSpec,
    options: SolveOptions, *, seed: int, cache: bool = True, reporter=None, timings: dict[str, float] | None = None,
):
    """The robust solve and its out-of-sample check (the hook of :func:`camplace.pipeline.run`).

    Parameters
    ----------
    instance, cands, pts
        The run's instance, candidates and points.
    nominal_matrix : (m, n) scipy.sparse.csr_matrix or camplace.visibility.bits.BitMatrix
        The nominal visibility matrix (its ``nnz`` and ``shape`` are read; a binary run's
        scenarios are then cast and stacked as bits, :func:`scenario_matrix` with ``bits``).
    weights : (m,) float64
        The row weights the run maximises.
    nominal : camplace.solver.SolverResult
        The nominal optimum.
    spec : RobustSpec
    options : SolveOptions
        The run's solver options, as the nominal solve got them; its memory budget also caps the
        scenarios' visibility.
    seed : int
        The run seed (scenario draws).
    timings : dict or None
        Wall times are added here (``robust.visibility``, ``robust.solve``, ``robust.evaluation``).

    Returns
    -------
    result : camplace.solver.SolverResult
        The robust answer (the nominal one, untouched, when both sigmas are 0).
    record : dict
        The ``robust`` entry of ``solution.json``: ``settings``, ``in_sample``
        (per system: mean and p10 of the sampled objective), ``out_of_sample`` (per system:
        mean, p10, min, max on fresh scenarios, and ``values``), ``seed_streams``.
    """
    timings = {} if timings is None else timings
    mode, views = options.mode, options.views if options.mode == "multiview" else 2
    memory_budget_bytes = options.memory_budget_bytes
    check_request(spec, mode, options.min_angle_deg, options.engine)
    record: dict[str, Any] = {
        "settings": spec_record(spec),
        "seed_streams": {"in_sample": IN_SAMPLE_STREAM, "out_of_sample": OUT_OF_SAMPLE_STREAM},
    }
    if spec.zero:
        # every installation is the nominal one: the robust problem IS the nominal problem
        value = float(nominal.objective)
        record["in_sample"] = {"robust": {"mean": value, "p10": value}, "nominal": {"mean": value, "p10": value}}
        values = np.full(spec.eval_scenarios, value)
        record["out_of_sample"] = {name: {**_summary(values), "values": values.tolist()} for name in ("robust", "nominal")}
        record["note"] = "zero pose error: the nominal answer"
        return nominal, record
    n = nominal_matrix.shape[1]
    t0 = time.perf_counter()
    stacked = scenario_matrix(
        instance, cands, pts, spec, seed=seed, nominal_nnz=nominal_matrix.nnz, cache=cache,
        memory_budget_bytes=memory_budget_bytes, reporter=reporter, bits=True,
    )
    timings["robust.visibility"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ctx = reporter.stage("robust solve") if reporter is not None else _null()
    with ctx:
        res = solve_robust(stacked, weights, spec, options, positions=cands.positions, points=pts.positions,
                           incumbents=[nominal.selected])
    timings["robust.solve"] = time.perf_counter() - t0
    in_sample = {}
    for name, sel in (("robust", res.selected), ("nominal", nominal.selected)):
        v = scenario_values(stacked, weights, spec.scenarios, sel, mode=mode, views=views)
        in_sample[name] = {"mean": float(np.mean(v)), "p10": order_p10(v)}
    record["in_sample"] = in_sample
    record["nominal_solution"] = {
        "selected": [int(j) for j in nominal.selected], "status": nominal.status, "objective": float(nominal.objective),
        "bound": float(nominal.bound) if math.isfinite(nominal.bound) else None,
    }
    record["stacked_shape"] = [int(stacked.shape[0]), int(n)]
    record["stacked_nnz"] = int(stacked.nnz)
    del stacked
    t0 = time.perf_counter()
    oos = out_of_sample(
        instance, cands, pts, weights, {"robust": res.selected, "nominal": nominal.selected}, spec, seed=seed,
        mode=mode, views=views, cache=cache, memory_budget_bytes=memory_budget_bytes, reporter=reporter,
    )
    timings["robust.evaluation"] = time.perf_counter() - t0
    record["out_of_sample"] = {name: {**_summary(v), "values": [float(x) for x in v]} for name, v in oos.items()}
    return res, record


class _null:
    def __enter__(self):
        return lambda _n=1: None

    def __exit__(self, *exc):
        return False
