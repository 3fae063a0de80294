"""Independent oracles for the planner: objective and feasibility from first principles, and enumeration.

Nothing here calls camplace.plan; it only uses numpy and the problem's raw arrays.
"""

from __future__ import annotations

import itertools
import math

import numpy as np


def set_value(q: np.ndarray, w: np.ndarray, cols, mode: str, views: int = 2) -> float:
    """Mode value of a pose set on dense rows ``q`` (m, n) with weights ``w``, summed row by row."""
    total = 0.0
    for i in range(q.shape[0]):
        vals = [q[i, j] for j in cols if q[i, j] > 0]
        if mode == "maxcover":
            total += w[i] if vals else 0.0
        elif mode == "quality":
            total += w[i] * (max(vals) if vals else 0.0)
        else:
            total += w[i] if len(vals) >= views else 0.0
    return total


def moves_ok(pos_a: np.ndarray, pos_b: np.ndarray, reach: float) -> bool:
    """Some assignment of the agents at pos_a to pos_b moves each at most ``reach`` (all permutations)."""
    k = len(pos_a)
    for perm in itertools.permutations(range(k)):
        if all(math.dist(pos_a[a], pos_b[perm[a]]) <= reach * (1 + 1e-9) + 1e-9 for a in range(k)):
            return True
    return False


def plan_violations(plan: np.ndarray, positions: np.ndarray, starts_s, speed: float, start_pos=None, start_time_s=None) -> list[str]:
    """Rule breaks of a (k, P) plan, the reach recomputed from the phases' start times and the speed."""
    out = []
    k, P = plan.shape
    for p in range(P):
        if len(set(int(j) for j in plan[:, p])) != k:
            out.append(f"phase {p}: repeated pose")
    for a in range(k):
        if start_pos is not None:
            reach = speed * (starts_s[0] - start_time_s)
            if math.dist(positions[plan[a, 0]], start_pos[a]) > reach * (1 + 1e-9) + 1e-9:
                out.append(f"agent {a}: start too far")
        for p in range(P - 1):
            reach = speed * (starts_s[p + 1] - starts_s[p])
            if math.dist(positions[plan[a, p]], positions[plan[a, p + 1]]) > reach * (1 + 1e-9) + 1e-9:
                out.append(f"agent {a}: phase {p} -> {p + 1} too far")
    return out


def _compatible(pa: np.ndarray, pb: np.ndarray, reach: float) -> np.ndarray:
    """(La, Lb) bool: pose sets pa[i] (k, 3) can move onto pb[j] by some permutation within reach."""
    k = pa.shape[1]
    out = np.zeros((pa.shape[0], pb.shape[0]), dtype=bool)
    for perm in itertools.permutations(range(k)):
        d = np.linalg.norm(pa[:, None, :, :] - pb[None, :, list(perm), :], axis=3)
        out |= np.all(d <= reach * (1 + 1e-9) + 1e-9, axis=2)
    return out


def enumerate_best(q_phases, w_phases, positions, k, reach, mode, views=2, start_pos=None, start_reach=math.inf):
    """The best plan by enumeration: a DP over all k-sets per phase (exact). Returns (value, sets) or (-inf, None)."""
    n = positions.shape[0]
    sets = list(itertools.combinations(range(n), k))
    ps = positions[np.array(sets)]  # (L, k, 3)
    P = len(q_phases)
    vals = [np.array([set_value(q_phases[p], w_phases[p], s, mode, views) for s in sets]) for p in range(P)]
    score = vals[0].copy()
    if start_pos is not None:
        ok0 = _compatible(np.asarray(start_pos, dtype=float)[None], ps, start_reach)[0]
        score[~ok0] = -np.inf
    back = []
    for p in range(1, P):
        ok = _compatible(ps, ps, reach[p - 1])
        cand = np.where(ok, score[:, None], -np.inf)
        arg = cand.argmax(axis=0)
        back.append(arg)
        score = cand[arg, np.arange(len(sets))] + vals[p]
    i = int(np.argmax(score))
    if not np.isfinite(score[i]):
        return -math.inf, None
    seq = [i]
    for arg in reversed(back):
        seq.append(int(arg[seq[-1]]))
    return float(score[i]), [sets[j] for j in reversed(seq)]


def best_static(q_phases, w_phases, n, k, mode, views=2) -> float:
    """Best single pose set for every phase, by enumeration."""
    return max(sum(set_value(q, w, s, mode, views) for q, w in zip(q_phases, w_phases))
               for s in itertools.combinations(range(n), k))


def best_per_phase(q_phases, w_phases, n, k, mode, views=2) -> float:
    """Sum over phases of each phase's best pose set, by enumeration."""
    return sum(max(set_value(q, w, s, mode, views) for s in itertools.combinations(range(n), k))
               for q, w in zip(q_phases, w_phases))
