"""The result of a max-coverage solve."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

__all__ = ["EngineOutcome", "SolverResult", "STATUSES", "jsonable", "relative_gap"]

STATUSES = ("optimal", "feasible", "infeasible", "unknown")


def relative_gap(bound: float, objective: float) -> float:
    """``(bound - objective) / max(|bound|, 1e-12)``, never negative.

    Parameters
    ----------
    bound : float
        Proven upper bound.
    objective : float
        Value of the incumbent.

    Returns
    -------
    float
    """
    if not (math.isfinite(bound) and math.isfinite(objective)):
        return math.inf
    return max(0.0, (bound - objective) / max(abs(bound), 1e-12))


def jsonable(value: Any) -> Any:
    """Convert numpy scalars/arrays (and nested containers) to plain JSON types.

    Non-finite floats become None so that ``json.dumps(..., allow_nan=False)`` works.
    """
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist"):  # numpy scalar or array
        return jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass(frozen=True)
class SolverResult:
    """Chosen cameras and the proof quality of the choice.

    Attributes
    ----------
    selected : tuple of int
        Sorted 0-based column indices of the ORIGINAL matrix (exactly ``k`` of them when feasible).
    status : str
        ``"optimal"`` (proven), ``"feasible"`` (stopped early; ``bound`` is still valid),
        ``"infeasible"`` or ``"unknown"`` (no solution).
    objective : float
        Weight covered by ``selected``, recomputed in float64 on the original matrix.
    bound : float
        Proven upper bound on the optimum (``== objective`` when optimal).
    gap : float
        ``(bound - objective) / max(|bound|, 1e-12)``; 0.0 when optimal.
    engine : str
        Engine that produced the result (``"exact"``, ``"mip"``, ``"cpsat"``).
    time_s : float
        Wall time of the whole solve including presolve, seconds.
    stats : dict
        JSON-serialisable details: sizes before/after presolve, nodes, timings, scaling.
    """

    selected: tuple[int, ...]
    status: str
    objective: float
    bound: float
    gap: float
    engine: str
    time_s: float
    stats: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {self.status!r}")

    @property
    def is_optimal(self) -> bool:
        """True when the result is proven optimal."""
        return self.status == "optimal"

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dict (infinite floats become None)."""
        return {
            "selected": [int(j) for j in self.selected],
            "status": self.status,
            "objective": jsonable(float(self.objective)),
            "bound": jsonable(float(self.bound)),
            "gap": jsonable(float(self.gap)),
            "engine": self.engine,
            "time_s": float(self.time_s),
            "stats": jsonable(self.stats),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "SolverResult":
        """Inverse of :meth:`to_dict` (None floats become +inf for bound/gap, nan for objective)."""

        def num(v: Any, default: float) -> float:
            return default if v is None else float(v)

        return cls(
            selected=tuple(sorted(int(j) for j in data["selected"])),
            status=str(data["status"]),
            objective=num(data.get("objective"), math.nan),
            bound=num(data.get("bound"), math.inf),
            gap=num(data.get("gap"), math.inf),
            engine=str(data["engine"]),
            time_s=float(data.get("time_s", 0.0)),
            stats=dict(data.get("stats", {})),
        )

    def to_json(self) -> str:
        """JSON text of :meth:`to_dict`."""
        return json.dumps(self.to_dict(), sort_keys=True)


@dataclass(frozen=True)
class EngineOutcome:
    """The one outcome type between an engine (or a route, or the linear-model backend) and
    :func:`camplace.solver.solve`, before the final checks (status ``optimal`` when the gap closed,
    the gap, the common stats) make it a :class:`SolverResult`. Which columns ``selected`` indexes
    is the producer's to say: an engine's, those of the matrix it was given (the presolved
    instance's REDUCED indices, the free columns, or the input's); a route's, the ORIGINAL matrix's,
    fixed cameras included.

    Attributes
    ----------
    selected : tuple of int, or None
        Column indices (None, or empty for some engines, when no solution was found; None from the
        linear-model backend, which answers with ``values``).
    status : str
        One of :data:`STATUSES`.
    bound : float
        Proven bound on the optimum (upper when maximising, lower for set cover), in original
        weight (or cost) units; the linear-model backend's in the model's objective units (+-inf
        when unknown).
    stats : dict
        JSON-serialisable details gathered so far (``solve`` adds the common entries).
    engine : str
        The engine that found ``selected`` (``"exact"``, ``"mip"``, ``"cpsat"``, ``"local-search"``).
    objective : float
        The value of ``selected`` where the producer reports it (a route: on the original data;
        setcover: the cost of the new cameras), else NaN.
    values : (n_vars,) float64 ndarray or None
        The linear-model backend's variable values (None elsewhere, or when it found no solution).
    """

    selected: tuple[int, ...] | None
    status: str
    bound: float
    stats: dict[str, Any] = field(default_factory=dict)
    engine: str = "exact"
    objective: float = math.nan
    values: Any = None
