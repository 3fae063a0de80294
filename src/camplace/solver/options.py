"""The options of one solve, in one frozen dataclass, and the command-line options that build it.

:class:`SolveOptions` holds everything :func:`camplace.solver.solve` takes besides the data (the
matrix, the weights, the camera and point positions), like ``options=`` of
``scipy.optimize.minimize``. It checks itself once, when it is made (one-line
:class:`~camplace.errors.CamplaceError` messages); the checks that need the data (index ranges,
``k`` against the allowed candidates) stay in :func:`~camplace.solver.solve`.

:func:`add_solver_options` adds the solver's flags to an ``argparse`` parser (``run`` and
``solve``), :func:`options_from_args` builds the :class:`SolveOptions` from the parsed namespace.

Imports nothing heavy (the command line builds its parser from this module).
"""

from __future__ import annotations

import argparse
import numbers
from dataclasses import dataclass, field, fields, replace
from typing import Any

from camplace.errors import CamplaceError
from camplace.names import ENGINES, MODES, TEAM_MODES

__all__ = ["SolveOptions", "add_solver_options", "options_from_args", "parse_index_list"]


@dataclass(frozen=True)
class SolveOptions:
    """How to choose the cameras (everything :func:`camplace.solver.solve` takes but the data).

    Attributes
    ----------
    mode : {"maxcover", "quality", "multiview", "setcover"}
        The formulation (:mod:`camplace.solver.api`).
    k : int or None
        Number of NEW cameras (every mode but ``setcover``, which must not get it).
    views : int
        multiview: cameras needed per point.
    min_angle_deg : float or None
        multiview: minimum angle at the point between two of its views, degrees.
    required_fraction : float
        setcover: fraction of the coverable weight to observe, in (0, 1].
    fixed, forbidden : tuple of int
        Candidate columns always kept / never chosen.
    min_distance_m : float or None
        Minimum distance between any two chosen cameras (fixed included), metres.
    engine : {"auto", "exact", "mip", "cpsat"}
    time_limit_s : float or None
        Wall-clock limit, seconds.
    costs : (n,) array_like or None
        setcover: camera costs (default 1 each). Not compared or hashed.
    memory_budget_bytes : int or None
        Cap on the memory any engine or model may use (``--memory-budget-gb``).
    search_seed : int
        setcover: seed of the local search (the solver's own seed; the run's ``--seed``, which
        draws candidates and points, is another one). Recorded as ``search_seed``.
    iterations : int or None
        setcover: iteration budget of the local search.
    team : TeamConstraints or None
        A camera team's constraints (:class:`camplace.solver.problem.team.TeamConstraints`: per
        model counts, budget, zone quotas, one camera per pose); modes ``maxcover`` and
        ``setcover``. With cardinality ``"budget"`` ``k`` may be None (any number of cameras).
        Not compared or hashed.
    threads : int or None
        Threads the solve may use (presolve's kernels, the exact search, OR-Tools' CP-SAT workers,
        the set-cover searches): 1 to the cores this process may use; None (default): the process's
        setting (``--threads``, :func:`camplace._cores.set_threads`), else every allowed core. The
        exact engine's answer is the same at every count. Not compared or recorded.
    """

    mode: str = "maxcover"
    k: int | None = None
    views: int = 2
    min_angle_deg: float | None = None
    required_fraction: float = 1.0
    fixed: tuple[int, ...] = ()
    forbidden: tuple[int, ...] = ()
    min_distance_m: float | None = None
    engine: str = "auto"
    time_limit_s: float | None = None
    costs: Any = field(default=None, compare=False, repr=False)
    memory_budget_bytes: int | None = None
    search_seed: int = 0
    iterations: int | None = None
    team: Any = field(default=None, compare=False, repr=False)
    threads: int | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fixed", () if self.fixed is None else tuple(self.fixed))
        object.__setattr__(self, "forbidden", () if self.forbidden is None else tuple(self.forbidden))
        _check(self)

    def replace(self, **changes: Any) -> "SolveOptions":
        """A copy with ``changes`` (checked again)."""
        return replace(self, **changes)

    @property
    def reads_geometry(self) -> bool:
        """Whether :func:`camplace.solver.solve` reads the camera and point positions: a minimum
        angle or distance, or multiview with fixed cameras (solved as the angle engine's problem
        at 0 degrees: :func:`camplace.solver.api._fixed_views_as_angle`)."""
        return (self.min_angle_deg is not None or self.min_distance_m is not None
                or (self.mode == "multiview" and bool(self.fixed)))

    def record(self) -> dict[str, Any]:
        """The ``options`` record of ``solution.json`` (the solver's part): JSON-ready, ``views`` and
        ``min_angle_deg`` None outside multiview, ``required_fraction`` and ``search_seed`` None
        outside setcover."""
        return {
            "mode": self.mode,
            "k": None if self.mode == "setcover" or self.k is None else int(self.k),
            "views": int(self.views) if self.mode == "multiview" else None,
            "min_angle_deg": None if self.min_angle_deg is None else float(self.min_angle_deg),
            "required_fraction": float(self.required_fraction) if self.mode == "setcover" else None,
            "fixed": sorted(int(j) for j in self.fixed),
            "forbidden": sorted(int(j) for j in self.forbidden),
            "min_distance_m": None if self.min_distance_m is None else float(self.min_distance_m),
            "engine": self.engine,
            "time_limit_s": None if self.time_limit_s is None else float(self.time_limit_s),
            "search_seed": int(self.search_seed) if self.mode == "setcover" else None,
            **({"team": self.team.record()} if self.team is not None else {}),
        }


#: Names of the :class:`SolveOptions` fields (the keyword options of :func:`camplace.solver.solve`).
OPTION_NAMES: tuple[str, ...] = tuple(f.name for f in fields(SolveOptions))


def _check(o: SolveOptions) -> None:
    """One-line errors for options that are wrong whatever the data (same messages as the solver's)."""
    if o.mode not in MODES:
        raise CamplaceError(f"unknown mode {o.mode!r} (choose one of {', '.join(MODES)})")
    if o.engine not in ENGINES:
        raise CamplaceError(f"unknown solver engine {o.engine!r} (choose one of {', '.join(ENGINES)})")
    if o.time_limit_s is not None and not (float(o.time_limit_s) > 0.0):
        raise CamplaceError(f"time_limit_s must be > 0 seconds, got {o.time_limit_s!r}")
    if o.memory_budget_bytes is not None and not o.memory_budget_bytes > 0:
        raise CamplaceError(f"the memory budget must be > 0 bytes, got {o.memory_budget_bytes!r}")
    if o.threads is not None:
        from camplace._cores import check_threads

        try:
            check_threads(o.threads)
        except ValueError as e:
            raise CamplaceError(str(e)) from None
    if o.min_distance_m is not None and not (float(o.min_distance_m) >= 0.0):
        raise CamplaceError(f"min_distance_m must be >= 0, got {o.min_distance_m!r}")
    if o.min_angle_deg is not None:
        if o.mode != "multiview":
            raise CamplaceError("min_angle_deg applies to mode 'multiview' only")
        if not (0.0 <= float(o.min_angle_deg) <= 180.0):
            raise CamplaceError(f"min_angle_deg must be within 0..180, got {o.min_angle_deg!r}")
    if o.mode == "multiview":
        v = o.views
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or int(v) < 1:
            raise CamplaceError(f"views must be an integer >= 1, got {v!r}")
        if o.min_angle_deg is not None and int(v) < 2:
            raise CamplaceError("min_angle_deg needs views >= 2")
    if o.team is not None:
        if not all(hasattr(o.team, a) for a in ("violations", "cardinality", "record")):  # no import: this module stays light
            raise CamplaceError(f"team must be a TeamConstraints, got {type(o.team).__name__}")
        if o.mode not in TEAM_MODES:
            raise CamplaceError(f"team constraints apply to modes {', '.join(TEAM_MODES)} only, not {o.mode!r}")
    if o.mode == "setcover":
        if o.k is not None:
            raise CamplaceError("mode 'setcover' chooses the number of cameras itself: do not give k")
        frac = float(o.required_fraction)
        if not (0.0 < frac <= 1.0):
            raise CamplaceError(f"required_fraction must be in (0, 1], got {o.required_fraction!r}")
    elif o.k is not None and (isinstance(o.k, bool) or not isinstance(o.k, numbers.Integral)):
        raise CamplaceError(f"k must be an integer number of cameras for mode {o.mode!r}, got {o.k!r}")


# ----------------------------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------------------------


def parse_index_list(text: str, name: str) -> tuple[int, ...]:
    """``"1,2, 5"`` -> ``(1, 2, 5)``; empty -> ``()``."""
    out = []
    for part in (text or "").split(","):
        part = part.strip()
        if not part:
            continue
        try:
            out.append(int(part))
        except ValueError:
            raise CamplaceError(f"--{name}: expected comma-separated candidate indices, got {part!r}") from None
    return tuple(out)


def add_solver_options(p: argparse.ArgumentParser, *, k_default: str, memory_budget: bool = True) -> None:
    """Add the solver's flags (``--mode``, ``--k``, ``--views``, ``--min-angle``,
    ``--required-fraction``, ``--engine``, ``--time-limit``, ``--fixed``, ``--forbidden``,
    ``--min-distance`` and, with ``memory_budget``, ``--memory-budget-gb``) to ``p``.

    Parameters
    ----------
    p : argparse.ArgumentParser
    k_default : str
        Where ``--k`` comes from when not given (for the help text), e.g. ``"the instance's k"``.
    memory_budget : bool
        Add ``--memory-budget-gb`` (``run`` has its own, which also caps the visibility stage).
    """
    p.add_argument("--mode", choices=MODES, default="maxcover",
                   help="formulation: maxcover (default), quality, multiview (>= --views cameras), setcover (fewest cameras)")
    p.add_argument("--k", type=int, default=None, help=f"number of new cameras (all modes but setcover; default: {k_default})")
    p.add_argument("--views", type=int, default=2, help="multiview: cameras that must observe a point (default 2)")
    p.add_argument("--min-angle", type=float, default=None, dest="min_angle",
                   help="multiview: minimum angle between two views at a point, degrees")
    p.add_argument("--required-fraction", type=float, default=1.0, dest="required_fraction",
                   help="setcover: share of the coverable weight to observe (default 1)")
    p.add_argument("--engine", choices=ENGINES, default="auto", help="solver engine (default auto)")
    p.add_argument("--time-limit", type=float, default=None, dest="time_limit",
                   help="solver time limit, seconds (default: run: the instance's; solve: the run's, from its solution.json)")
    p.add_argument("--fixed", default="", help="candidate columns kept as existing cameras, e.g. 3,17 (k new ones are added)")
    p.add_argument("--forbidden", default="", help="candidate columns never chosen, e.g. 5,6")
    p.add_argument("--min-distance", type=float, default=None, dest="min_distance",
                   help="minimum distance between chosen cameras, metres")
    if memory_budget:
        p.add_argument("--memory-budget-gb", type=float, default=None, dest="memory_budget_gb",
                       help="memory the solver may use (default: 60%% of the memory available); larger models fall back or stop")


def options_from_args(args: argparse.Namespace, **changes: Any) -> SolveOptions:
    """The :class:`SolveOptions` of a command line parsed with :func:`add_solver_options`.

    Parameters
    ----------
    args : argparse.Namespace
    **changes
        Fields to set instead of the namespace's (e.g. ``k`` taken from a stored run).

    Returns
    -------
    SolveOptions
    """
    gb = getattr(args, "memory_budget_gb", None)
    if gb is not None and not gb > 0:
        raise CamplaceError(f"--memory-budget-gb: must be > 0, got {gb}")
    if args.time_limit is not None and not args.time_limit > 0:
        raise CamplaceError(f"--time-limit: must be > 0 seconds, got {args.time_limit}")
    values: dict[str, Any] = {
        "mode": args.mode,
        "k": args.k,
        "views": args.views,
        "min_angle_deg": args.min_angle,
        "required_fraction": args.required_fraction,
        "fixed": parse_index_list(args.fixed, "fixed"),
        "forbidden": parse_index_list(args.forbidden, "forbidden"),
        "min_distance_m": args.min_distance,
        "engine": args.engine,
        "time_limit_s": args.time_limit,
        "memory_budget_bytes": None if gb is None else int(gb * 2**30),
    }
    values.update(changes)
    return SolveOptions(**values)
