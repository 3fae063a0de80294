"""Set cover by reductions, row-weighting local search and a Lagrangian bound (SCIP / CP-SAT after).

``minimise sum_j c_j x_j`` such that every row is covered (or, for a partial cover, the covered
row weight reaches ``need``), on a 0/1 matrix. Four steps:

1. **Reductions** (:func:`reduce_cover`), each keeping some optimal cover: columns of cost 0 are
   taken; a row only one column covers forces that column; a row whose columns include all the
   columns of another row is dropped (covering the other covers it; full covers only); a column
   whose rows lie inside a column at most as dear is dropped; a column dearer than covering each
   of its rows by its cheapest other column is dropped; identical rows of a partial cover are
   merged. Repeated until nothing changes. Subset tests run on bitsets (compiled), candidates
   taken from an item's rarest element.
2. **Local search** (:class:`LocalSearch`): greedy (best gain per cost) plus redundancy removal,
   then row-weighting local search after RWLS (Gao, Weise and Li 2015): every row has a penalty
   weight, raised while it is uncovered, and a column's score is the
   penalty it would cover (outside the solution) or leave uncovered (inside). Whenever the
   solution covers everything it is recorded and its least useful column removed, so the search
   always looks for a cover one column cheaper than the best. With equal costs (full covers) a
   move is RWLS's (:func:`_sckernels.search_rwls`): remove the column of least loss (not the one
   just added), add the column of largest gain covering a random uncovered row that configuration
   checking allows (a removed column waits until a column sharing a row with it is added), the
   penalties raised on the rows the removed column leaves uncovered (close to
   fontanf/setcoveringsolver's row weighting 1, :data:`RWLS_PENALTY_MODE`), each by its own step,
   larger for rows few columns cover (:data:`RWLS_ROW_STEP`, also their starting penalty and the
   greedy's row weights); ``rwls=False`` gives
   the best joint swap of its row weighting 2 instead (add one of the columns covering a random
   uncovered row and remove one column, chosen together, candidates tried by decreasing gain with
   an exact cut-off). With costs, RWLS moves with gain / cost ratios, penalties raised on every
   uncovered row. Tabu: the column just added is not removed next, the one just removed not
   added back; ties go to the column unchanged for longest. Scores are incremental: a move only touches the rows
   whose coverage changes between 0, 1 and 2 (the only coverer of a row is kept as the sum of
   its coverers' indices). The search stops at an iteration budget, a time limit, the bound, or
   on patience, counted in work units (score updates), not seconds: a seed and an iteration
   budget (or no time limit) give the same answer on any machine; a time limit (checked between
   compiled chunks) makes it depend on speed. The long search (after the model, or instead of it)
   restarts from its best cover less a random fifth of its columns, completed greedily, penalties
   back at their start, whenever the work since its last improvement or restart reaches a Luby
   sequence of units (:data:`RESTART_WORK_PER_NNZ`), and runs beside a second search with its own
   random stream started from the same cover, one thread each (:func:`run_searches`,
   :data:`SEARCH_THREADS`, the cores the process may use): the time a search needs to find the
   next cover varies by orders of magnitude between runs, so several independent tries do better
   than one long one.
3. **Lower bound** (:func:`lagrangian_bound`): subgradient optimisation of the Lagrangian
   relaxation of the covering rows (Beasley 1990), rounded up for integral costs; it also stops
   the local search once the two meet (the cover is then optimal).
4. **Exact model**: SCIP (``mip``) or CP-SAT (``cpsat``) on the reduced instance, started from
   the local search cover (a hint: SCIP takes it as its incumbent and cuts off everything not
   cheaper; CP-SAT also gets the row ``cost <= its cost``). The cheaper cover and the larger bound
   are kept; without a proof, the search resumes. ``auto`` runs SCIP only when the reduced
   instance is small (:data:`AUTO_MODEL_NNZ`) and, with equal costs, the gap is at most two columns
   (the LP bound of a unicost cover is flat: SCIP closes no wider gap on a large instance), or for
   a trial of at most :data:`AUTO_TRIAL_S` seconds when the gap is at most
   :data:`AUTO_TRIAL_GAP_COLUMNS` columns and the reduced instance tiny (:data:`AUTO_TRIAL_NNZ`); otherwise the search answer comes back
   with the Lagrangian bound (status ``feasible`` and its gap unless the two meet).
   Its memory is estimated first (:func:`cover_model_bytes`); a model that would not fit is skipped
   with a warning (``stats["memory_fallback"]``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from camplace._cores import thread_count
from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline, as_deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.engines.setcover import _kernels as K
from camplace.solver.engines.setcover.reduce import CoverReduction, cover_bytes, reduce_cover
from camplace.solver.result import EngineOutcome

__all__ = ["CoverReduction", "reduce_cover", "small_cover_test", "LocalSearch", "local_search", "lagrangian_bound", "solve_cover",
           "AUTO_MODEL_NNZ", "cover_bytes", "cover_model_bytes", "patience_work", "restart_unit_work",
           "run_searches", "search_threads"]

if TYPE_CHECKING:
    from camplace.solver.engines.setcover.reduce_bits import RowBits

log = logging.getLogger(__name__)

AUTO_MODEL_NNZ = 1_500_000  # auto hands the reduced instance to SCIP up to this many nonzeros ...
AUTO_MODEL_GAP_COLUMNS = 2  # ... and, with equal costs, a gap to the Lagrangian bound of this many columns
# a gap of a few columns more on a small reduced instance: SCIP for a short trial all the same (a
# 173 x 54 instance with a gap of 3 columns: proven in 0.25 s, where the search alone ends at its
# patience unproven; 14 random instances of 94-205 columns with gaps of 5-18 columns: none closed
# within 3 s, so wider gaps get no trial)
AUTO_TRIAL_NNZ = 20_000
AUTO_TRIAL_GAP_COLUMNS = 4
AUTO_TRIAL_S = 2.0
# exact test of a unicost cover (small_cover_test): covers of at most this many columns plus one are
# tested for one column fewer, within this many word operations (and, with a time limit, what this
# many words a second allow in a quarter of the time left)
EXACT_MAX_COLUMNS = 5
EXACT_WORK = 200_000_000  # about 2 s on the 2-core VM (a hopeless 3,000 x 1,500 random test: 4e9 in 40 s)
EXACT_WORDS_PER_S = 100_000_000
_CHUNK_S = 0.02  # target seconds per compiled local-search call (the clock is read in between)
_LAG_PATIENCE = 10
_LAG_MAX_ITERS = 3000
_LS_SHARE_BEFORE_MODEL = 0.5  # with a time limit: the first search's share of the time left at most
_LAG_SHARE = 0.15  # share of the time left for the Lagrangian bound
_MODEL_SHARE = 0.75  # share of the time left for SCIP / CP-SAT (the search resumes after it)
MAX_CANDIDATES = 16  # columns tried per move (by decreasing gain) in the best-swap search
# unit costs, full cover: RWLS moves (:func:`_sckernels.search_rwls`); penalties raised on the rows the
# removed column leaves uncovered (1; 2 also after the removals from a cover, as in
# fontanf/setcoveringsolver's row weighting 1) or on every uncovered row after the move (0, RWLS)
RWLS_PENALTY_MODE = 1
# configuration checking of the RWLS moves: 0 none (only the column just removed is tabu), 1 freed by
# additions, 2 freed by additions and removals
RWLS_CC_MODE = 1
# penalty step of a row with equal costs and a full cover (RWLS moves and joint swaps):
# max(1, floor(RWLS_ROW_STEP / columns covering it)), also its starting penalty (rows few columns
# cover weigh more; integers keep the incremental sums exact); 0: every step 1
RWLS_ROW_STEP = 10_000
# restarts of the long search (solve_cover's second phase): from the best cover less this share of
# its columns, after RESTART_WORK_PER_NNZ work units a nonzero (between the limits) times the Luby sequence
RESTART_DROP = 0.2
RESTART_WORK_PER_NNZ = 10_000
RESTART_WORK_MIN = 50_000_000
RESTART_WORK_MAX = 2_000_000_000
# searches side by side in solve_cover's second phase (one thread each, at most the cores available)
SEARCH_THREADS = 2
# patience of the search, in work units (score updates; about 1e8 to 1e9 a second): 2,000 per
# nonzero of the reduced matrix, between these limits; a tenth of it for the first search (the one
# before SCIP / CP-SAT may run)
PATIENCE_PER_NNZ = 2000
PATIENCE_WORK_MIN = 1_000_000
PATIENCE_WORK = 500_000_000


def patience_work(nnz: int, before_model: bool = False) -> int:
    """Work without improvement after which the search stops (see :data:`PATIENCE_PER_NNZ`)."""
    p = int(min(max(PATIENCE_PER_NNZ * nnz, PATIENCE_WORK_MIN), PATIENCE_WORK))
    return p // 10 if before_model else p


def restart_unit_work(nnz: int) -> int:
    """Work unit of the restart schedule (see :data:`RESTART_WORK_PER_NNZ`)."""
    return int(min(max(RESTART_WORK_PER_NNZ * nnz, RESTART_WORK_MIN), RESTART_WORK_MAX))


# ----------------------------------------------------------------------------------------------
# local search
# ----------------------------------------------------------------------------------------------


def _splitmix(seed: int) -> np.uint64:
    z = (int(seed) + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z ^= z >> 31
    return np.uint64(z or 1)


class LocalSearch:
    """Row-weighting local search on a :class:`CoverReduction` (state in plain arrays).

    Parameters
    ----------
    red : CoverReduction
    seed : int
        Seed of the search's own random generator (same seed and iterations: same answer).
    start : sequence of int, optional
        Reduced columns of a cover to start from instead of the greedy one.
    max_cand, joint
        Candidates per move and use of the joint swap (equal costs, ``rwls`` False).
    rwls : bool, optional
        RWLS moves (:func:`_sckernels.search_rwls`); default: when every reduced column costs the
        same and every row must be covered (never for partial covers).
    stream : int
        Random stream of the seed (0: the seed's own; others: independent streams of the same seed,
        for searches run side by side).
    """

    def __init__(self, red: CoverReduction, seed: int = 0, start: Any = None,
                 max_cand: int = MAX_CANDIDATES, joint: bool = True, rwls: bool | None = None,
                 stream: int = 0) -> None:
        self.max_cand = int(max_cand)
        self.joint = bool(joint)
        m, n = red.shape
        unit = bool(n == 0 or np.all(red.cost == red.cost[0]))
        self.rwls = (unit and not red.partial) if rwls is None else bool(rwls) and not red.partial
        self.red = red
        self.pinc = np.ones(m)
        if unit and not red.partial and RWLS_ROW_STEP > 0:
            self.pinc = np.maximum(1.0, np.floor(RWLS_ROW_STEP / np.maximum(np.diff(red.rptr), 1)))
        self.cc_mode = int(RWLS_CC_MODE)
        self.restart_work: int | None = None
        self.stamp = np.zeros(n, dtype=np.int64)
        self.best = np.zeros(n, dtype=np.int8)
        self.ist = np.zeros(K.N_IST, dtype=np.int64)
        self.fst = np.zeros(K.N_FST, dtype=np.float64)
        self.rng = np.array([_splitmix(seed) if stream == 0 else _splitmix(int(_splitmix(seed)) + int(stream))],
                            dtype=np.uint64)
        self.need = red.need * (1.0 - 1e-12) if red.partial else -1.0
        self._start(start)
        self.best[:] = self.x
        self.fst[K.BEST_COST] = self.fst[K.COST]
        self.ist[K.BEST_WORK] = self.ist[K.EPOCH_WORK] = self.ist[K.WORK]
        self.best_time = time.perf_counter()  # clock (perf_counter) when the best cover was found, to a chunk
        self.greedy_cost = float(self.fst[K.COST])

    def _start(self, start: Any) -> None:
        """Fresh state (every row uncovered, penalties at their start, configuration checking
        cleared), then the greedy cover completed from the columns ``start`` (None: none)."""
        red = self.red
        m, n = red.shape
        # configuration checking of RWLS: last event of every row, removal event of every column, counter
        self.rchg = np.zeros(m, dtype=np.int64)
        self.cblk = np.zeros(n, dtype=np.int64)
        self.clk = np.zeros(1, dtype=np.int64)
        self.x = np.zeros(n, dtype=np.int8)
        self.cov = np.zeros(m, dtype=np.int32)
        self.csum = np.zeros(m, dtype=np.int64)
        if red.partial:
            pos = red.roww[red.roww > 0]
            self.pw = red.roww / (float(pos.mean()) if pos.size else 1.0)
        else:
            self.pw = self.pinc.copy()
        col_of = np.repeat(np.arange(n), np.diff(red.cptr))
        self.score = np.bincount(col_of, weights=self.pw[red.crow], minlength=n).astype(np.float64)
        self.sel = np.zeros(n, dtype=np.int32)
        self.selpos = np.full(n, -1, dtype=np.int32)
        self.unc = np.arange(m, dtype=np.int32)
        self.uncpos = np.arange(m, dtype=np.int32)
        self.ist[K.NSEL] = 0
        self.ist[K.NUNC] = m
        self.ist[K.LADD] = self.ist[K.LREM] = -1
        self.fst[K.COST] = self.fst[K.COVW] = 0.0
        with ctrl_c_deferred():
            if start is not None:
                move = self._args()
                move = move[:6] + move[7:]  # add_col takes no 'need'
                for j in start:
                    if not self.x[int(j)]:
                        K.add_col(int(j), *move)
            K.greedy(*self._args())
        if not self.feasible():
            raise CamplaceError("setcover local search: the start is not a cover (internal error)")

    def restart(self) -> None:
        """Start again from the best cover less a random share (:data:`RESTART_DROP`) of its columns,
        completed greedily, with every penalty back at its start (the best cover is kept; the
        random draws come from the search's own generator: deterministic)."""
        cols = np.flatnonzero(self.best)
        r = np.random.default_rng(int(K._rand(self.rng)))
        keep = cols[r.random(cols.size) >= RESTART_DROP]
        self._start(keep)
        self.ist[K.EPOCH_WORK] = self.ist[K.WORK]
        self.ist[K.RESTARTS] += 1

    def _args(self) -> tuple:
        r = self.red
        return (r.cptr, r.crow, r.rptr, r.rcol, r.cost, r.roww, self.need, self.x, self.cov, self.csum, self.pw,
                self.score, self.stamp, self.sel, self.selpos, self.unc, self.uncpos, self.ist, self.fst)

    def feasible(self) -> bool:
        """True when the current solution is a cover."""
        if self.red.partial:
            return float(self.red.roww[self.cov > 0].sum()) >= self.need
        return int(self.ist[K.NUNC]) == 0

    @property
    def iterations(self) -> int:
        """Iterations run so far."""
        return int(self.ist[K.IT])

    @property
    def best_cost(self) -> float:
        """Cost of the best cover (reduced instance, forced columns excluded)."""
        return float(self.fst[K.BEST_COST])

    @property
    def best_iteration(self) -> int:
        """Iteration at which the best cover was found."""
        return int(self.ist[K.BEST_IT])

    def run(self, *, max_iterations: int | None = None, deadline: Deadline | None = None, target: float = -math.inf,
            patience: int | None = None, stop: threading.Event | None = None,
            reached: threading.Event | None = None) -> str:
        """Search until an iteration budget, a time limit, the target cost or a stall.

        Parameters
        ----------
        max_iterations : int, optional
            Stop once this many iterations have run in total (deterministic).
        deadline : Deadline, optional
            Stop when it expires (checked between compiled chunks; default: no limit).
        target : float
            Stop once the best cost is at most this (a lower bound: the cover is then optimal).
        patience : int, optional
            Stop once the work since the best cover (score updates, a count that does not depend
            on the machine) exceeds ``patience`` plus the work it took to find it: the search goes
            on while improvements keep coming (deterministic).
        stop : threading.Event, optional
            Stop once it is set (checked between compiled chunks).
        reached : threading.Event, optional
            Set when the target is reached.

        With :attr:`restart_work` set, the search restarts (:meth:`restart`) whenever the work since
        its last improvement or restart reaches ``restart_work`` times the next term of the Luby
        sequence (1, 1, 2, 1, 1, 2, 4, ...): short runs often, long ones now and then, which suits
        searches whose time to the best cover varies by orders of magnitude from run to run.

        Returns
        -------
        str
            Why it stopped: ``"target"``, ``"iterations"``, ``"patience"``, ``"time"``, ``"stuck"``
            (every row covered, the required weight not reached) or ``"stopped"``.
        """
        chunk = 64
        stop_it = np.iinfo(np.int64).max if max_iterations is None else int(max_iterations)
        pat = np.iinfo(np.int64).max // 4 if patience is None else int(patience)
        args = self._args()
        improved = int(self.ist[K.IMPROVED])
        while True:
            if deadline is not None and deadline.expired():
                return "time"
            if stop is not None and stop.is_set():
                return "stopped"
            rst = np.iinfo(np.int64).max // 4 if self.restart_work is None else \
                int(self.restart_work) * _luby(int(self.ist[K.RESTARTS]) + 1)
            c0 = time.perf_counter()
            with ctrl_c_deferred():
                if self.rwls:
                    code = K.search_rwls(*args[:17], self.best, self.ist, self.fst, self.rng, chunk, float(target),
                                         stop_it, pat, self.rchg, self.cblk, self.clk, self.cc_mode,
                                         RWLS_PENALTY_MODE, self.pinc, rst)
                else:
                    code = K.search(*args[:17], self.best, self.ist, self.fst, self.rng, chunk, float(target),
                                    stop_it, pat, self.max_cand, self.joint, self.pinc, rst)
            dt = time.perf_counter() - c0
            if self.ist[K.IMPROVED] != improved:
                improved = int(self.ist[K.IMPROVED])
                self.best_time = c0 + dt
            if code == 5:
                self.restart()
                args = self._args()
                continue
            if code == 1 and reached is not None:
                reached.set()
            if code:
                return {1: "target", 2: "iterations", 3: "stuck", 4: "patience"}[code]
            if dt < _CHUNK_S / 2:
                chunk = min(chunk * 2, 1 << 22)
            elif dt > _CHUNK_S * 2:
                chunk = max(1, chunk // 2)

    def best_cover(self) -> np.ndarray:
        """Reduced columns of the best cover after removing redundant columns (dearest first)."""
        fresh = LocalSearch(self.red, start=np.flatnonzero(self.best))
        return np.flatnonzero(fresh.x).astype(np.int64)


def _luby(i: int) -> int:
    """The ``i``-th term (from 1) of the Luby sequence 1, 1, 2, 1, 1, 2, 4, 1, 1, 2, 1, 1, 2, 4, 8, ..."""
    while True:
        k = i.bit_length()
        if i == (1 << k) - 1:
            return 1 << (k - 1)
        i -= (1 << (k - 1)) - 1


def search_threads() -> int:
    """Searches run side by side (:func:`run_searches`): :func:`camplace._cores.thread_count` (``--threads``,
    ``SolveOptions.threads``, else the cores this process may use), at most :data:`SEARCH_THREADS`."""
    return max(1, min(SEARCH_THREADS, thread_count()))


def run_searches(searches: list[LocalSearch], *, deadline: Deadline | None = None, target: float = -math.inf,
                 patience: int | None = None) -> list[str]:
    """Run several searches side by side, one thread each (the compiled kernels release the GIL).

    With a deadline that has a limit, the first to reach ``target`` stops the others (the answer then depends on
    the machine's speed, as any timed search does); without one, each runs to its own end, so the
    outcome of every search is that of running it alone (deterministic).

    Returns
    -------
    list of str
        Why each stopped (:meth:`LocalSearch.run`).
    """
    if len(searches) == 1:
        return [searches[0].run(deadline=deadline, target=target, patience=patience)]
    ev = threading.Event()  # also stops the threads when the main one is interrupted (Ctrl-C)
    with ThreadPoolExecutor(max_workers=len(searches), thread_name_prefix="setcover-search") as ex:
        timed = deadline is not None and deadline.limit is not None
        futs = [ex.submit(s.run, deadline=deadline, target=target, patience=patience, stop=ev,
                          reached=ev if timed else None) for s in searches]
        try:
            return [f.result() for f in futs]
        finally:
            ev.set()


def local_search(red: CoverReduction, *, seed: int = 0, max_iterations: int | None = None,
                 deadline: Deadline | None = None, target: float = -math.inf,
                 patience: int | None = None) -> tuple[np.ndarray, float, dict[str, Any]]:
    """Greedy plus row-weighting local search (see :class:`LocalSearch`).

    Returns
    -------
    selected : (s,) int64
        Reduced columns of the best cover found (no redundant column).
    cost : float
        Its cost (forced columns excluded).
    stats : dict
    """
    t0 = time.perf_counter()
    ls = LocalSearch(red, seed=seed)
    why = ls.run(max_iterations=max_iterations, deadline=deadline, target=target, patience=patience)
    sel = ls.best_cover()
    cost = float(red.cost[sel].sum())
    return sel, cost, {"greedy_cost": ls.greedy_cost, "cost": cost, "iterations": ls.iterations,
                       "best_iteration": ls.best_iteration, "stopped_by": why, "seed": int(seed),
                       "time_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------------------------------
# lower bound
# ----------------------------------------------------------------------------------------------


def _integral(values: np.ndarray) -> bool:
    return bool(np.all(values == np.rint(values)))


def _rounded_bound(lst: np.ndarray, integral: bool) -> float:
    """The best Lagrangian value of ``lst`` (:mod:`._kernels`' state) less a floating-point margin,
    rounded up when the costs are integers, and not below 0."""
    bound = float(lst[K.LBEST]) - 1e-9 * (float(lst[K.LMAG]) + 1.0)
    return max(float(math.ceil(bound)) if integral else bound, 0.0)


def lagrangian_bound(red: CoverReduction, upper: float, *, max_iterations: int = _LAG_MAX_ITERS,
                     deadline: Deadline | None = None) -> tuple[float, dict[str, Any]]:
    """Lower bound on the reduced instance's optimum (forced columns excluded).

    Parameters
    ----------
    red : CoverReduction
    upper : float
        Cost of a known cover (the step size aims at it).
    max_iterations : int
    deadline : Deadline, optional
        Stop when it expires (default: no limit); the bound found so far stays valid.

    Returns
    -------
    bound : float
        ``L(u)`` minus a floating-point margin, rounded up when the costs are integers, and at
        least the cheapest column's cost (rows left to cover take a column). When ``upper`` is
        that cost already, that at once (no steps); with integer costs the steps stop once the
        rounded bound reaches ``upper``.
    stats : dict
    """
    t0 = time.perf_counter()
    m, n = red.shape
    if m == 0:
        return 0.0, {"iterations": 0, "time_s": 0.0}
    integral = _integral(red.cost)
    cheapest = float(red.cost.min()) if n else 0.0  # a row (or weight) left to cover takes a column
    if upper <= cheapest + 1e-9 * max(1.0, abs(cheapest)):
        # the cover at hand is one cheapest column: nothing to prove beyond that (a partial cover that
        # one camera reaches took 6 s of subgradient steps to bound at 1 before)
        return cheapest, {"lagrangian": None, "bound": cheapest, "iterations": 0, "converged": True,
                          "time_s": time.perf_counter() - t0, "by": "one column: the cheapest column's cost"}
    # start: every row gets its cheapest cost per covered row
    col_of = np.repeat(np.arange(n), np.diff(red.cptr))
    per = (red.cost / np.maximum(np.diff(red.cptr), 1))[col_of]
    u = np.full(m, np.inf)
    np.minimum.at(u, red.crow, per)
    u[~np.isfinite(u)] = 0.0
    best_u = u.copy()
    lst = np.array([2.0, -1e300, 0.0, 0.0])
    done = 0
    chunk = 4
    converged = False
    while done < max_iterations:
        if deadline is not None and deadline.expired():
            break
        c0 = time.perf_counter()
        with ctrl_c_deferred():
            r = K.lagrangian(red.cptr, red.crow, red.rptr, red.cost, red.roww, red.need if red.partial else -1.0, u,
                             best_u, lst, min(chunk, max_iterations - done), float(upper), _LAG_PATIENCE)
        if r < 0:
            converged = True
            break
        done += r
        if time.perf_counter() - c0 < _CHUNK_S:
            chunk *= 2
        if _rounded_bound(lst, integral) >= upper - 1e-9 * abs(upper):
            break  # integer costs: a bound that rounds up to the cover's cost proves it
    value = float(lst[K.LBEST])
    bound = max(_rounded_bound(lst, integral), cheapest)
    return bound, {"lagrangian": value, "bound": bound, "iterations": int(done), "converged": converged,
                   "time_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------------------------------
# exact test for a small unicost cover
# ----------------------------------------------------------------------------------------------


def _unicost(red: CoverReduction) -> bool:
    return bool(red.cost.size and np.all(red.cost == red.cost[0]) and red.cost[0] > 0)


def small_cover_test(red: CoverReduction, sel: np.ndarray, lower: float, deadline: Deadline | None = None
                     ) -> tuple[np.ndarray, float, dict[str, Any]]:
    """Prove a unicost cover of few columns optimal, or find a smaller one, by an exact test.

    With ``s`` columns in the cover ``sel`` and at most :data:`EXACT_MAX_COLUMNS`, the compiled
    depth-first search :func:`_kernels.small_cover` looks for a cover of at most ``s - 1``
    columns (branching on the columns of the uncovered row with the fewest, each explored column
    banned from its later siblings, a node cut when ``s - 1`` times the most rows one column adds
    is below the rows left). None: the optimum is ``s`` columns (the bound). One: it becomes the
    cover and the test repeats one column lower, down to the lower bound. The search is cut at
    :data:`EXACT_WORK` word operations (a count, not a time: the same on any machine), and with a
    time limit at what :data:`EXACT_WORDS_PER_S` words a second allow in a quarter of the time
    left. A Lagrangian bound of 3 on comet-67p-bunker 10,000 x 50,000 (3,164 x 2,276 reduced rows
    and columns) leaves a gap the search and SCIP do not close; this test shows in well under a
    second that no 3 columns cover it.

    Parameters
    ----------
    red : CoverReduction
        A full cover with equal costs.
    sel : (s,) int64
        Reduced columns of a cover.
    lower : float
        A lower bound on the reduced instance's optimum (the test stops there).
    deadline : Deadline, optional

    Returns
    -------
    selected : (s',) int64
        The cover (``sel`` or a smaller one found).
    bound : float
        A lower bound: ``s' x cost`` when proven, else ``lower``.
    stats : dict
    """
    t0 = time.perf_counter()
    unit = float(red.cost[0])
    sel = np.asarray(sel, dtype=np.int64)
    st: dict[str, Any] = {"columns": int(sel.size), "result": "skipped"}
    m, n = red.shape
    if sel.size - 1 > EXACT_MAX_COLUMNS or sel.size == 0:
        st["result"] = f"skipped ({sel.size} columns, tested up to {EXACT_MAX_COLUMNS + 1})"
        return sel, lower, st
    need = n * ((m + 63) // 64) * 8 * 2 + 16 * n
    if need > memory_budget_bytes():
        st["result"] = f"skipped (bitsets {need / 2**20:.0f} MiB over the memory budget)"
        return sel, lower, st
    max_work = EXACT_WORK
    left = None if deadline is None else deadline.left()
    if left is not None:
        max_work = int(min(max_work, max(0.0, 0.25 * left) * EXACT_WORDS_PER_S))
    cb = K.column_bitsets(red.cptr, red.crow, m)
    full = np.zeros(cb.shape[1] * 64, dtype=bool)
    full[:m] = True
    bound = lower
    work = np.zeros(1, dtype=np.int64)
    while sel.size - 1 >= max(1, math.ceil(lower / unit - 1e-9)):
        k = int(sel.size) - 1
        unc = np.zeros((k + 1, cb.shape[1]), dtype=np.uint64)
        unc[0] = np.packbits(full, bitorder="little").view(np.uint64)
        banned = np.zeros(n, dtype=np.int64)
        chosen = np.full(k, -1, dtype=np.int64)
        with ctrl_c_deferred():
            r = K.small_cover(cb, red.rptr, red.rcol, unc, 0, k, banned, chosen, work, np.int64(max_work))
        if r == 1:
            sel = np.sort(chosen[chosen >= 0])
            if not _is_cover(red, sel):
                raise CamplaceError("setcover exact test: its cover misses a row (internal error)")
            continue
        if r == 0:
            bound = float(sel.size) * unit
            st["result"] = "proven"
        else:
            st["result"] = "work limit"
        break
    else:  # the cover has ceil(lower / cost) columns (or one): optimal
        bound = float(sel.size) * unit
        st["result"] = "proven"
    st.update({"cover_columns": int(sel.size), "work": int(work[0]), "max_work": int(max_work),
               "time_s": time.perf_counter() - t0})
    return sel, bound, st


# ----------------------------------------------------------------------------------------------
# SCIP / CP-SAT on the reduced instance
# ----------------------------------------------------------------------------------------------


def _model_cover(red: CoverReduction, hint: np.ndarray, upper: float, backend: str,
                 deadline: Deadline) -> tuple[np.ndarray | None, str, float, dict[str, Any]]:
    """Solve the reduced instance with SCIP or CP-SAT, the cover ``hint`` as a start and
    ``cost <= upper`` as a cutoff. Returns (reduced columns or None, status, lower bound, stats)."""
    from camplace.solver.engines.mip.linear import LinearModel, solve_model

    m, n = red.shape
    model = LinearModel(maximize=False)
    x = model.add_vars(n, obj=red.cost)
    rptr, rcol = red.rptr, red.rcol
    integral = _integral(red.cost)
    if not red.partial:
        for i in range(m):
            cols = rcol[rptr[i] : rptr[i + 1]]
            model.add_row(x[cols], np.ones(cols.size), lo=1.0)
    else:
        y = model.add_vars(m)
        for i in range(m):
            cols = rcol[rptr[i] : rptr[i + 1]]
            model.add_row(np.append(x[cols], y[i]), np.append(np.ones(cols.size), -1.0), lo=0.0)
        total = float(red.roww.sum())
        scale_f = 1.0 / max(total, 1e-300)
        s_int = 2.0**30 / max(total, 1e-300)
        # CP-SAT needs integers: weights rounded UP keep every true cover feasible; the answer is
        # re-checked against the exact requirement
        cint = np.ceil(red.roww * s_int).astype(np.int64)
        model.add_row(y, red.roww * scale_f, lo=red.need * scale_f,
                      int_variant=(cint, float(math.ceil(red.need * s_int)), math.inf))
    if integral and backend == "cpsat":  # cutoff row: nothing dearer than the local-search cover
        # (SCIP takes the hint as its incumbent and cuts off on it; an explicit dense objective row
        # makes its root LP far slower and its time limit unreliable)
        model.add_row(x, red.cost, hi=float(upper), int_variant=(red.cost.astype(np.int64), -math.inf, float(upper)))
    start = {int(x[j]): (1.0 if j in set(hint.tolist()) else 0.0) for j in range(n)}
    out = solve_model(model, backend, deadline=deadline, hint=start)
    stats = dict(out.stats)
    stats["status"] = out.status
    bound = out.bound
    if math.isfinite(bound) and integral:
        bound = float(math.ceil(bound - 1e-6))
    if out.values is None:
        return None, out.status, bound, stats
    sel = np.flatnonzero(out.values[x] > 0.5).astype(np.int64)
    return sel, out.status, bound, stats


def cover_model_bytes(red: CoverReduction, backend: str) -> int:
    """Estimated peak memory of the SCIP / CP-SAT model of a reduced instance
    (:func:`camplace.solver.engines.mip.linear.model_bytes`)."""
    from camplace.solver.engines.mip.linear import model_bytes

    m, n = red.shape
    if red.partial:  # a y variable per row, y_i in each covering row, the weight row
        return model_bytes(backend, n + m, m + 1, red.nnz + 2 * m)
    return model_bytes(backend, n, m + 1, red.nnz + n)


def _is_cover(red: CoverReduction, sel: np.ndarray) -> bool:
    m, n = red.shape
    if m == 0:
        return True
    hit = np.zeros(m, dtype=bool)
    for j in sel.tolist():
        hit[red.crow[red.cptr[j] : red.cptr[j + 1]]] = True
    if red.partial:
        return float(red.roww[hit].sum()) >= red.need * (1.0 - 1e-12)
    return bool(hit.all())


# ----------------------------------------------------------------------------------------------
# the whole pipeline
# ----------------------------------------------------------------------------------------------


def _model_choice(engine: str, red: CoverReduction, upper: float, lower: float
                  ) -> tuple[str | None, str, float | None]:
    """The model to run after the first search (or None), if none why, and the most seconds it
    may take beyond its share of the time (None: its share).

    ``mip`` / ``cpsat``: always. ``auto``: SCIP when the reduced instance has at most
    :data:`AUTO_MODEL_NNZ` nonzeros and, with equal costs, the gap to the Lagrangian bound is at
    most :data:`AUTO_MODEL_GAP_COLUMNS` columns: the LP bound of a unicost cover is flat (the
    Lagrangian one a little below it), so SCIP closes no wider gap on a large instance, and the
    time is better spent searching. A gap of at most :data:`AUTO_TRIAL_GAP_COLUMNS` columns on a
    reduced instance of at most :data:`AUTO_TRIAL_NNZ` nonzeros: SCIP all the same, for at most
    :data:`AUTO_TRIAL_S` seconds.
    """
    if engine in ("mip", "cpsat"):
        return engine, "", None
    if red.nnz > AUTO_MODEL_NNZ:
        return None, f"reduced instance has {red.nnz} nonzeros (auto runs SCIP up to {AUTO_MODEL_NNZ})", None
    gap = upper - lower
    if red.cost.size and np.all(red.cost == red.cost[0]) and gap > AUTO_MODEL_GAP_COLUMNS * red.cost[0] * (1 + 1e-9):
        if red.nnz <= AUTO_TRIAL_NNZ and gap <= AUTO_TRIAL_GAP_COLUMNS * red.cost[0] * (1 + 1e-9):
            return "mip", "", AUTO_TRIAL_S
        return None, f"equal costs and a gap of {gap / red.cost[0]:g} columns (SCIP would not close it)", None
    return "mip", "", None


def solve_cover(pattern: sp.csr_matrix | RowBits, costs: np.ndarray, weights: np.ndarray | None = None,
                need: float | None = None, *, engine: str = "auto", deadline: Deadline | None = None,
                seed: int = 0, max_iterations: int | None = None) -> EngineOutcome:
    """Reductions, local search, Lagrangian bound and (if it applies) SCIP / CP-SAT.

    Parameters
    ----------
    pattern : (m, n) scipy.sparse.csr_matrix or RowBits
        Canonical 0/1 matrix; every row is covered by some column. Or its row bitsets
        (:class:`camplace.solver.engines.setcover.reduce_bits.RowBits`): the reductions then read
        the bitsets (:func:`~camplace.solver.engines.setcover.reduce_bits.reduce_cover_bits`, the
        same reduced instance) and only the reduced instance becomes lists.
    costs : (n,) float64
        Costs >= 0.
    weights : (m,) float64, optional
        Row weights > 0 (partial cover).
    need : float, optional
        Weight a partial cover must reach; None: cover every row.
    engine : {"auto", "mip", "cpsat"}
        ``auto``: SCIP after the first search when :func:`_model_choice` says it can close the
        gap; ``mip`` / ``cpsat``: always (unless the bound already proves the cover optimal).
    deadline : Deadline, optional
        The solve's deadline (default: none), for everything; the shares below are of the time
        left at the call. The Lagrangian bound gets at most 15 % of it; the first
        search stops on a short patience (:func:`patience_work`) or after half of what is left;
        the model gets three quarters of what is then left; if there is still no proof, the
        search goes on until the time limit. Without a time limit the second search stops on the
        full patience: once the work since its best cover exceeds :func:`patience_work` plus the
        work it took to find it.
    seed : int
        Seed of the local search.
    max_iterations : int, optional
        Iteration budget of the local search, which then does not stop on patience. With it and
        no time limit the answer is fully deterministic (so is it without either: patience counts
        work, not time); with a time limit it depends on the machine's speed.

    Returns
    -------
    EngineOutcome
        ``selected``: input columns of the cover (None: no cover found); ``objective``: its cost;
        ``bound``: a lower bound on the optimal cost; ``engine``: ``"local-search"`` when no model
        ran, else the model's backend (``"mip"``, ``"cpsat"``).
    """
    t0 = time.perf_counter()
    deadline = as_deadline(deadline)
    left = deadline.left
    total = left()  # the time left at the call (None: no limit)

    m, n = pattern.shape
    on_bits = getattr(pattern, "format", None) == "rowbits"
    if on_bits:  # the reductions read the row bitsets; the reduced instance's lists are checked there
        from camplace.solver.engines.setcover.reduce_bits import reduce_bits_bytes, reduce_cover_bits

        need_bytes = reduce_bits_bytes(m, n)
    else:
        need_bytes = cover_bytes(m, n, int(pattern.nnz))
    budget = memory_budget_bytes()
    if need_bytes > budget:
        memory_fallback(OverBudget(need_bytes, budget, f"the set-cover search ({m} x {n}, {pattern.nnz} nonzeros)"),
                        stats=None, asked=True, then=None)  # nothing answers without it
    c = np.asarray(costs, dtype=np.float64)
    red = reduce_cover_bits(pattern, c, weights, need) if on_bits else reduce_cover(pattern, c, weights, need)
    stats: dict[str, Any] = {"reduction": dict(red.stats)}
    mr, nr = red.shape
    if mr == 0 or (red.partial and red.need <= 0):
        sel = _prune_input(pattern, c, weights, need, red.input_columns(()))
        cost = float(c[list(sel)].sum())
        stats["time_s"] = time.perf_counter() - t0
        return EngineOutcome(sel, "optimal", cost, stats, engine="local-search", objective=cost)
    ls = LocalSearch(red, seed=seed)
    lb, stats["lagrangian"] = lagrangian_bound(red, ls.best_cost, deadline=deadline.share(_LAG_SHARE))
    # first search: short patience, at most half the time left (the whole budget with an iteration budget)
    why = ls.run(max_iterations=max_iterations, deadline=deadline.share(_LS_SHARE_BEFORE_MODEL),
                 target=lb, patience=None if max_iterations is not None else patience_work(red.nnz, before_model=True))
    sel_r = ls.best_cover()
    cost_r = float(red.cost[sel_r].sum())
    found_s = ls.best_time - t0  # when the cover kept so far was found
    ls_stats = {"greedy_cost": ls.greedy_cost + red.forced_cost, "cost": cost_r + red.forced_cost,
                "iterations": ls.iterations, "best_iteration": ls.best_iteration, "work": int(ls.ist[K.WORK]),
                "stopped_by": why, "seed": int(seed)}
    stats["local_search"] = ls_stats
    bound_r = min(lb, cost_r)
    name = "local-search"
    proven = cost_r <= lb + 1e-9 * max(1.0, abs(cost_r))
    if not proven and not red.partial and _unicost(red) and not deadline.expired():
        # few columns: no cover with one column fewer, by an exact depth-first test (or a cheaper cover)
        sel_x, bound_x, stats["exact_test"] = small_cover_test(red, sel_r, lb, deadline)
        if sel_x.size < sel_r.size:
            sel_r, cost_r = sel_x, float(red.cost[sel_x].sum())
            found_s = time.perf_counter() - t0
        bound_r = max(bound_r, min(bound_x, cost_r))
        proven = cost_r <= bound_r + 1e-9 * max(1.0, abs(cost_r))
    backend, why_not, trial_s = _model_choice(engine, red, cost_r, lb)
    if not proven and backend is not None and cover_model_bytes(red, backend) > memory_budget_bytes():
        # the search's cover answers whichever engine was asked for: no error here
        memory_fallback(OverBudget(cover_model_bytes(red, backend), memory_budget_bytes(),
                                   f"the {'SCIP' if backend == 'mip' else 'CP-SAT'} model of the reduced {mr} x {nr} "
                                   f"set-cover instance ({red.nnz} nonzeros)"),
                        stats, asked=False, then="kept the local-search cover and its bound")
        backend = None
    if not proven and backend is None and why_not:
        stats["model_skipped"] = why_not
    if not proven and backend is not None:
        name = backend
        stats["model_bytes"] = int(cover_model_bytes(red, backend))  # its estimate, for the run's memory figures
        model_deadline = deadline.share(_MODEL_SHARE)
        if trial_s is not None:  # a wide gap on a tiny instance: a short try
            model_deadline = model_deadline.within(trial_s)
            stats["model_trial_s"] = trial_s
        msel, mstatus, mbound, mstats = _model_cover(red, sel_r, cost_r, backend, model_deadline)
        stats["model"] = mstats
        if msel is not None and _is_cover(red, msel):
            mcost = float(red.cost[msel].sum())
            if mcost < cost_r - 1e-9 * max(1.0, abs(cost_r)):
                sel_r, cost_r = msel, mcost
                found_s = time.perf_counter() - t0
        elif msel is not None:
            log.warning("setcover: the %s answer does not cover the required weight (integer rounding); kept the "
                        "local-search cover", backend)
        if mstatus == "optimal":
            bound_r = cost_r
        elif math.isfinite(mbound):
            bound_r = max(bound_r, min(mbound, cost_r))
        proven = cost_r <= bound_r + 1e-9 * max(1.0, abs(cost_r))
    rem = left()
    if not proven and why in ("patience", "time") and (rem is None or total is None or rem > 0.02 * total):
        # the search goes on from where it was, with restarts, beside a second one started from its
        # best cover (own random stream), one thread each: until the time limit when there is one,
        # else each with the full patience counted from now
        ls.ist[K.BEST_WORK] = max(int(ls.ist[K.BEST_WORK]), int(ls.ist[K.WORK]) // 2)
        searches = [ls] + [LocalSearch(red, seed=seed, stream=k, start=np.flatnonzero(ls.best))
                           for k in range(1, search_threads())]
        for s in searches:
            s.restart_work = restart_unit_work(red.nnz)
        whys = run_searches(searches, deadline=deadline.share(0.97), target=bound_r,
                            patience=None if rem is not None else patience_work(red.nnz))
        costs2 = [s.best_cost for s in searches]
        k_best = int(np.argmin(costs2))  # ties: the first
        sel2 = searches[k_best].best_cover()
        cost2 = float(red.cost[sel2].sum())
        if cost2 < cost_r - 1e-9 * max(1.0, abs(cost_r)):
            sel_r, cost_r = sel2, cost2
            found_s = searches[k_best].best_time - t0
            proven = cost_r <= bound_r + 1e-9 * max(1.0, abs(cost_r))
        ls_stats.update({"cost": cost2 + red.forced_cost, "iterations": sum(s.iterations for s in searches),
                         "best_iteration": searches[k_best].best_iteration,
                         "work": int(sum(int(s.ist[K.WORK]) for s in searches)), "stopped_by": whys[k_best],
                         "resumed": True, "searches": len(searches),
                         "restarts": int(sum(int(s.ist[K.RESTARTS]) for s in searches)), "best_search": k_best})
    sel = _prune_input(pattern, c, weights, need, red.input_columns(sel_r))
    cost = float(c[list(sel)].sum())
    bound = min(bound_r + red.forced_cost, cost)
    status = "optimal" if proven else "feasible"
    if status == "optimal":
        bound = cost
    stats["time_s"] = time.perf_counter() - t0
    stats["time_to_best_s"] = max(0.0, found_s)
    log.info("setcover: %s cost %.9g bound %.9g (%s) in %.2f s", status, cost, bound, name, stats["time_s"])
    return EngineOutcome(sel, status, bound, stats, engine=name, objective=cost)


def _prune_input(pattern: sp.csr_matrix | RowBits, costs: np.ndarray, weights: np.ndarray | None, need: float | None,
                 selected: tuple[int, ...]) -> tuple[int, ...]:
    """Drop columns of a cover of the input that are not needed, dearest first (cost 0 ones
    included): the cost never rises and no camera is kept for nothing."""
    m = pattern.shape[0]
    sel = list(selected)
    if not sel:
        return ()
    if getattr(pattern, "format", None) == "rowbits":  # row bitsets: the selected columns' rows alone
        col_rows = {j: pattern.column_rows(j) for j in sel}
    else:
        a = pattern.tocsc()
        col_rows = {j: a.indices[a.indptr[j] : a.indptr[j + 1]] for j in sel}
    cov = np.zeros(m, dtype=np.int64)
    for j in sel:
        cov[col_rows[j]] += 1
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=np.float64)
    got = float(w[cov > 0].sum())
    floor = None if need is None else float(need) * (1.0 - 1e-12)
    for j in sorted(sel, key=lambda j: (-costs[j], -j)):
        rows = col_rows[j]
        alone = rows[cov[rows] == 1]
        if floor is None:
            ok = alone.size == 0
        else:
            ok = got - float(w[alone].sum()) >= floor
        if ok:
            cov[rows] -= 1
            got -= float(w[alone].sum())
            sel.remove(j)
    return tuple(sorted(sel))
