"""A camera team's constraints as data: :class:`TeamConstraints` (issue 31).

One frozen object carries everything a mixed team imposes on the chosen columns, built once from
the :class:`~camplace.sampling.candidates.CandidateSet` and the instance's
:class:`~camplace.instance.schema.Team` (:meth:`TeamConstraints.from_team`, called by the pipeline
and ``camplace solve``) and handed to the solver in
:attr:`SolveOptions.team <camplace.solver.options.SolveOptions>`:

* per model ``m``: ``model_min[m] <= #chosen columns of model m <= model_max[m]``;
* cardinality: ``"exact"`` (``k`` new cameras, as without a team) or ``"budget"`` (any number of
  cameras; ``k``, when given, only caps the new ones);
* ``budget``: total cost of the chosen cameras (fixed ones included) ``<= budget``;
* per zone ``z``: ``zone_min[z] <= #chosen columns in z <= zone_max[z]``;
* at most one chosen column per physical pose (``pose``: the pose index of each column; a pose is
  offered once per model that may stand there).

Fixed cameras count in every one of these (they are part of the team); ``k`` counts new cameras.
:meth:`TeamConstraints.violations` checks a selection (the solver's answers, ``solution.json``'s
``team`` record and the tests all use it).

Imports nothing heavy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from camplace.errors import CamplaceError

__all__ = ["TeamConstraints", "pose_index", "CARDINALITIES"]

#: ``"exact"``: k new cameras; ``"budget"``: any number (at most k new ones when k is given).
CARDINALITIES = ("exact", "budget")


def pose_index(positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(n,) int64: the same index for columns standing at the same position with the same rotation
    (the columns of one physical pose, one per model), numbered in order of first appearance."""
    pos = np.ascontiguousarray(np.asarray(positions, dtype=np.float64).reshape(-1, 3))
    rot = np.ascontiguousarray(np.asarray(rotations, dtype=np.float64).reshape(len(pos), 9))
    key = np.concatenate([pos, rot], axis=1) + 0.0  # -0.0 -> 0.0
    if len(key) == 0:
        return np.zeros(0, dtype=np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    # renumber by first appearance so that the index does not depend on the sort order of floats
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return rank[np.asarray(inv).ravel()].astype(np.int64)


def _counts(values: Sequence[int | None], n: int, what: str) -> tuple:
    out = tuple(values)
    if len(out) != n:
        raise CamplaceError(f"team constraints: {len(out)} {what} for {n} entries")
    return out


@dataclass(frozen=True, eq=False)
class TeamConstraints:
    """Everything a camera team imposes on the chosen columns (see the module docstring).

    Attributes
    ----------
    model : (n,) int64
        Camera model of each column (index into ``model_names``).
    model_names : tuple of str
    model_min : tuple of int
    model_max : tuple of int or None
        Per model: cameras at least / at most (None: no limit).
    cost : (n,) float64
        Cost of each column (its model's cost).
    budget : float or None
        Largest total cost (None: none).
    zone_names : tuple of str
    zone_member : (n, z) bool
        Whether each column stands in each zone.
    zone_min : tuple of int
    zone_max : tuple of int or None
    pose : (n,) int64 or None
        Physical pose of each column (at most one chosen column per pose); None: no such limit.
    cardinality : {"exact", "budget"}
    """

    model: np.ndarray
    model_names: tuple[str, ...]
    model_min: tuple[int, ...]
    model_max: tuple[int | None, ...]
    cost: np.ndarray
    budget: float | None = None
    zone_names: tuple[str, ...] = ()
    zone_member: np.ndarray | None = None
    zone_min: tuple[int, ...] = ()
    zone_max: tuple[int | None, ...] = ()
    pose: np.ndarray | None = None
    cardinality: str = "exact"

    def __post_init__(self) -> None:
        model = np.asarray(self.model, dtype=np.int64).ravel()
        n = model.size
        nm = len(self.model_names)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "model_names", tuple(str(s) for s in self.model_names))
        object.__setattr__(self, "model_min", tuple(int(v) for v in _counts(self.model_min, nm, "model minimums")))
        object.__setattr__(self, "model_max", tuple(None if v is None else int(v)
                                                    for v in _counts(self.model_max, nm, "model maximums")))
        if n and (model.min() < 0 or model.max() >= nm):
            raise CamplaceError(f"team constraints: column models must be within 0..{nm - 1}")
        cost = np.asarray(self.cost, dtype=np.float64).ravel()
        if cost.size != n or not np.all(np.isfinite(cost)) or np.any(cost < 0):
            raise CamplaceError(f"team constraints: cost must be {n} finite values >= 0")
        object.__setattr__(self, "cost", cost)
        if self.budget is not None and not (math.isfinite(float(self.budget)) and float(self.budget) >= 0):
            raise CamplaceError(f"team constraints: budget must be a finite number >= 0, got {self.budget!r}")
        nz = len(self.zone_names)
        zm = np.zeros((n, 0), dtype=bool) if self.zone_member is None else np.asarray(self.zone_member, dtype=bool)
        if zm.shape != (n, nz):
            raise CamplaceError(f"team constraints: zone_member must have shape ({n}, {nz}), got {zm.shape}")
        object.__setattr__(self, "zone_member", zm)
        object.__setattr__(self, "zone_names", tuple(str(s) for s in self.zone_names))
        object.__setattr__(self, "zone_min", tuple(int(v) for v in _counts(self.zone_min, nz, "zone minimums")))
        object.__setattr__(self, "zone_max", tuple(None if v is None else int(v)
                                                   for v in _counts(self.zone_max, nz, "zone maximums")))
        if self.pose is not None:
            pose = np.asarray(self.pose, dtype=np.int64).ravel()
            if pose.size != n:
                raise CamplaceError(f"team constraints: pose must have {n} entries, got {pose.size}")
            object.__setattr__(self, "pose", pose)
        if self.cardinality not in CARDINALITIES:
            raise CamplaceError(f"team constraints: cardinality must be one of {', '.join(CARDINALITIES)}, "
                                f"got {self.cardinality!r}")

    # ------------------------------------------------------------------------------------------
    @classmethod
    def from_team(cls, team: Any, candidates: Any, *, cardinality: str | None = None) -> "TeamConstraints":
        """The constraints of an instance's ``team`` on a run's ``candidates``.

        Parameters
        ----------
        team : camplace.instance.schema.Team
        candidates : camplace.sampling.candidates.CandidateSet
            Its ``model`` (per column), ``zones`` (columns x zones), positions and rotations (the
            pose index).
        cardinality : {"exact", "budget"}, optional
            Default: ``"budget"`` when the team has a budget (any number of cameras within it),
            else ``"exact"`` (k cameras).
        """
        model = candidates.models() if hasattr(candidates, "models") else np.asarray(candidates.model)
        model = np.asarray(model, dtype=np.int64)
        n = model.size
        costs = np.array([float(m.cost) for m in team.models], dtype=np.float64)
        nz = len(team.zones)
        zones = getattr(candidates, "zones", None)
        if nz and zones is None:
            zones = np.stack([z.contains(np.asarray(candidates.positions)) for z in team.zones], axis=1)
        zm = np.zeros((n, 0), dtype=bool) if not nz else np.asarray(zones, dtype=bool).reshape(n, nz)
        if cardinality is None:
            cardinality = "budget" if team.budget is not None else "exact"
        return cls(
            model=model, model_names=tuple(m.name for m in team.models),
            model_min=tuple(int(m.min_count) for m in team.models),
            model_max=tuple(m.max_count for m in team.models),
            cost=costs[model] if n else np.zeros(0), budget=None if team.budget is None else float(team.budget),
            zone_names=tuple(z.name for z in team.zones), zone_member=zm,
            zone_min=tuple(int(z.min_cameras) for z in team.zones), zone_max=tuple(z.max_cameras for z in team.zones),
            pose=pose_index(candidates.positions, candidates.rotations), cardinality=cardinality,
        )

    # ------------------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of columns."""
        return int(self.model.size)

    def check_columns(self, n: int) -> None:
        """One-line error unless the constraints describe ``n`` columns."""
        if self.n != n:
            raise CamplaceError(f"team constraints describe {self.n} candidate columns but the matrix has {n}")

    def column_class(self) -> np.ndarray:
        """(n,) int64: columns of the same class (model, zones, cost) may stand in for each other in
        a dominance argument only when the pose limit is not involved; columns of different classes
        never (presolve must not drop one in favour of another class)."""
        key = np.concatenate([self.model[:, None].astype(np.float64), self.cost[:, None],
                              self.zone_member.astype(np.float64)], axis=1)
        if key.shape[0] == 0:
            return np.zeros(0, dtype=np.int64)
        _, inv = np.unique(key, axis=0, return_inverse=True)
        return np.asarray(inv, dtype=np.int64).ravel()

    def uses(self, selected: Sequence[int]) -> dict[str, Any]:
        """What ``selected`` uses: ``models`` (counts by name), ``cost``, ``zones`` (counts by name)."""
        sel = np.asarray(list(selected), dtype=np.int64)
        mc = np.bincount(self.model[sel], minlength=len(self.model_names)) if sel.size else np.zeros(len(self.model_names), int)
        zc = self.zone_member[sel].sum(axis=0) if sel.size else np.zeros(len(self.zone_names), int)
        return {"models": {nm: int(c) for nm, c in zip(self.model_names, mc)},
                "cost": float(self.cost[sel].sum()) if sel.size else 0.0,
                "zones": {zn: int(c) for zn, c in zip(self.zone_names, zc)}}

    def violations(self, selected: Sequence[int], *, k: int | None = None, fixed: Sequence[int] = (),
                   tol: float = 1e-9) -> list[str]:
        """The constraints ``selected`` (fixed cameras included) breaks, one line each ([] if none).

        ``k`` (new cameras) is checked as the cardinality says: exactly (``"exact"``) or at most
        (``"budget"``); not at all when None.
        """
        sel = sorted(int(j) for j in selected)
        out: list[str] = []
        u = self.uses(sel)
        for name, lo, hi in zip(self.model_names, self.model_min, self.model_max):
            c = u["models"][name]
            if c < lo or (hi is not None and c > hi):
                out.append(f"{c} {name} camera(s) (asked {lo}{'+' if hi is None else f'..{hi}'})")
        if self.budget is not None and u["cost"] > self.budget * (1 + tol) + tol:
            out.append(f"cost {u['cost']:g} over the budget {self.budget:g}")
        for name, lo, hi in zip(self.zone_names, self.zone_min, self.zone_max):
            c = u["zones"][name]
            if c < lo or (hi is not None and c > hi):
                out.append(f"{c} camera(s) in zone {name} (asked {lo}{'+' if hi is None else f'..{hi}'})")
        if self.pose is not None and sel:
            poses = self.pose[np.asarray(sel)]
            dup = _duplicates(poses)
            if dup.size:
                out.append(f"{dup.size} pose(s) hold more than one camera")
        if k is not None:
            new = len(set(sel) - {int(j) for j in fixed})
            if self.cardinality == "exact" and new != k:
                out.append(f"{new} new camera(s), asked exactly {k}")
            elif self.cardinality == "budget" and new > k:
                out.append(f"{new} new camera(s), asked at most {k}")
        return out

    def record(self) -> dict[str, Any]:
        """JSON-ready summary (for ``solver_stats`` and ``solution.json``)."""
        return {
            "cardinality": self.cardinality,
            "models": [{"name": nm, "min_count": lo, "max_count": hi}
                       for nm, lo, hi in zip(self.model_names, self.model_min, self.model_max)],
            "budget": self.budget,
            "zones": [{"name": zn, "min_cameras": lo, "max_cameras": hi}
                      for zn, lo, hi in zip(self.zone_names, self.zone_min, self.zone_max)],
            "one_per_pose": self.pose is not None,
        }


def _duplicates(values: np.ndarray) -> np.ndarray:
    """The values that occur more than once."""
    u, c = np.unique(values, return_counts=True)
    return u[c > 1]


def team_options(team: Any, candidates: Any, options: Any) -> Any:
    """``options`` (a :class:`~camplace.solver.options.SolveOptions`) carrying the constraints of
    ``team`` on ``candidates`` (the pipeline's and ``camplace solve``'s one place to build them).

    Unchanged when there is no team or the mode cannot enforce them (a mode outside
    :data:`camplace.names.TEAM_MODES`: the run then records ``team.enforced: false``); every
    mode enforces them today (maxcover, quality, multiview, setcover). With a budget the
    cardinality is ``"budget"``: any number of cameras within it, ``k`` dropped."""
    from camplace.names import TEAM_MODES

    if team is None or options.mode not in TEAM_MODES:
        return options
    tc = TeamConstraints.from_team(team, candidates)
    k = None if (options.mode == "setcover" or tc.cardinality == "budget") else options.k
    return options.replace(team=tc, k=k)
