"""Choose the best k cameras: proven-optimal maximum weighted coverage.

Input is a visibility matrix ``A`` (m points x n candidate cameras; any value > 0 means "observes")
and point weights. :func:`solve` chooses cameras under every formulation (``maxcover``,
``quality``, ``multiview``, ``setcover``; see :mod:`camplace.solver.api`); :func:`solve_maxcover`
is plain max coverage: exactly ``k`` distinct columns maximising the total weight of the rows
observed by at least one of them. Both report whether the answer is proven optimal, with a valid
bound.

Engines (all run on the :func:`presolve`-reduced instance):

``exact``
    Bound-pruned search over tuples of candidate clusters on row bitsets, for small k
    (:mod:`camplace.solver.engines.bitset.search`); the default for k <= 4.
``mip``
    SCIP through OR-Tools ``pywraplp``; the default for k > 4.
``cpsat``
    OR-Tools CP-SAT with integer-scaled weights, one worker per thread (``--threads`` /
    ``SolveOptions.threads``, else every allowed core).

``auto`` is decided by :func:`~camplace.solver.choose.choose_engine` (a pure function of the
problem's sizes, the :class:`~camplace.solver.options.SolveOptions` and the memory budget; its
reason is in ``stats["engine_choice"]``).

Layout (modelled on :mod:`scipy.optimize`: one entry, one options object, one result type, each
engine in its own private module):

* :mod:`~camplace.solver.api`: ``solve`` and ``solve_maxcover`` (the checks, the solve's one
  deadline, the final result); :mod:`~camplace.solver.routes` (the k-camera modes as one problem
  object, ``CoverProblem``, and the engine table ``ROUTES`` keyed by the engine choice's route);
  :mod:`~camplace.solver.options` (``SolveOptions`` and the command-line flags),
  :mod:`~camplace.solver.choose` (engine choice), :mod:`~camplace.solver.result` (``SolverResult``;
  ``EngineOutcome``, the one outcome type between an engine and ``solve``), :mod:`~camplace.solver.cli`.
* ``problem/``: input checks, objectives (what each mode counts), presolve, set-cover formats.
* ``engines/``: ``bitset/`` (the exact tuple search, the opposite-pairs bound), ``angle/``,
  ``quality/`` (tree, min-Gram, their portfolio), ``large_k/``, ``setcover/``, ``mip/`` (the linear
  model backend, the mode models, the max-coverage MIP / CP-SAT engines, the p10 model), and
  ``maxcover`` (the max-coverage engines within the memory budget); compiled kernels sit beside
  the engine that uses them.
* ``_support/``: the deadline, the memory budget, the best-first frontier, greedy heuristics and
  the row-bitset kernels shared by presolve and the engines.

This package imports no geometry code: it only sees matrices.
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr
from camplace.names import ENGINES, MODES

# Imported on first use, so that ``import camplace.solver`` (e.g. to read the names above, or for
# the command line's parser) compiles no kernels and loads no OR-Tools.
_LAZY = {
    "Presolved": "camplace.solver.problem.presolve",
    "presolve": "camplace.solver.problem.presolve",
    "SolverResult": "camplace.solver.result",
    "SolveOptions": "camplace.solver.options",
    "coverage_weight": "camplace.solver.problem.objectives",
    "solve": "camplace.solver.api",
    "mode_value": "camplace.solver.problem.objectives",
    "conflict_pairs": "camplace.solver.problem.checks",
    "choose_engine": "camplace.solver.choose",
    "solve_maxcover": "camplace.solver.api",
}

__getattr__ = lazy_getattr(__name__, _LAZY)


__all__ = ["ENGINES", "MODES", *sorted(_LAZY)]
