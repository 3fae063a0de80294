"""Choose the best k cameras: proven-optimal maximum weighted coverage.

Input is a visibility matrix ``A`` (m points x n candidate cameras; any value > 0 means "observes")
and point weights. :func:`solve` chooses cameras under every formulation (``maxcover``,
``quality``, ``multiview``, ``setcover``; see :mod:`camplace.solver.modes`); :func:`solve_maxcover`
is plain max coverage: exactly ``k`` distinct columns maximising the total weight of the rows
observed by at least one of them. Both report whether the answer is proven optimal, with a valid
bound.

Engines (all run on the :func:`presolve`-reduced instance):

``exact``
    Bound-pruned search over tuples of candidate clusters on row bitsets, for small k
    (:mod:`camplace.solver.bitset_exact`); the default for k <= 4.
``mip``
    SCIP through OR-Tools ``pywraplp``; the default for k > 4.
``cpsat``
    OR-Tools CP-SAT with integer-scaled weights, 2 workers.

``auto`` is decided by :func:`~camplace.solver.choose.choose_engine` (a pure function of the
problem's sizes, the :class:`~camplace.solver.options.SolveOptions` and the memory budget; its
reason is in ``stats["engine_choice"]``).

Modules: :mod:`~camplace.solver.options` (SolveOptions and the command-line flags),
:mod:`~camplace.solver.checks` (input checks), :mod:`~camplace.solver.objectives` (what each mode
counts), :mod:`~camplace.solver.choose` (engine choice), :mod:`~camplace.solver.modes` (``solve``:
runs the choice, falls back on memory), :mod:`~camplace.solver.portfolio` (the exact quality
engines), :mod:`~camplace.solver.greedy`, :mod:`~camplace.solver.models` (SCIP / CP-SAT models of
the modes, on :mod:`~camplace.solver._model`), :mod:`~camplace.solver.setcover` (the set-cover
mode), :mod:`~camplace.solver.result` (``SolverResult``, and ``ModeOutcome`` between an engine and
``solve``); the engines themselves in their own modules.

This package imports no geometry code: it only sees matrices.
"""

from __future__ import annotations

import sys
import types

from camplace._lazy import lazy_getattr
from camplace.names import ENGINES, MODES

# Imported on first use, so that ``import camplace.solver`` (e.g. to read the names above, or for
# the command line's parser) compiles no kernels and loads no OR-Tools.
_LAZY = {
    "Presolved": "camplace.solver.presolve",
    "presolve": "camplace.solver.presolve",
    "SolverResult": "camplace.solver.result",
    "SolveOptions": "camplace.solver.options",
    "coverage_weight": "camplace.solver._common",
    "solve": "camplace.solver.modes",
    "mode_value": "camplace.solver.objectives",
    "conflict_pairs": "camplace.solver.checks",
    "choose_engine": "camplace.solver.choose",
    "solve_maxcover": "camplace.solver.maxcover",
}

__getattr__ = lazy_getattr(__name__, _LAZY)


class _Package(types.ModuleType):
    """This package, where importing the submodule ``presolve`` does not hide the function ``presolve``.

    Python binds an imported submodule as an attribute of its package; the function of the same
    name is then found by the lazy ``__getattr__`` instead (``camplace.solver.presolve`` stays the
    module in ``sys.modules`` for ``from camplace.solver.presolve import ...``).
    """

    def __setattr__(self, name: str, value) -> None:
        if name == "presolve" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

__all__ = ["ENGINES", "MODES", *sorted(_LAZY)]
