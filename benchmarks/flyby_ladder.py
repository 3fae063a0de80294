"""The comet-flyby candidate ladder of issue 30: visibility matrices of ``camplace run comet-flyby
--seed 1 --points 5000`` (3 aims per position) at 500 / 2,000 / 8,000 / 32,000 positions, and the
solve of each in maxcover and in multiview (2 views, minimum angle 20 degrees) with one time limit.

Not a test. The matrices are computed once and cached (``camplace.visibility.cache``); the solve
is the pipeline's (:func:`camplace.pipeline.solve_stage`'s inputs: the event weights over all
frames, camera and point positions for the angle). Used by ``benchmarks/solver.py --ladder flyby``.
"""

from __future__ import annotations

import time
from typing import Any

LADDER_POSITIONS = (500, 2000, 8000, 32000)
POINTS = 5000
SEED = 1
MIN_ANGLE_DEG = 20.0


def flyby_inputs(positions: int, points: int = POINTS, seed: int = SEED) -> dict[str, Any]:
    """The solve's inputs of comet-flyby at ``positions`` candidate positions (cached visibility).

    Returns a dict: ``matrix`` (m, n; what ``camplace run`` solves: the column bitsets of a binary
    instance), ``weights`` (m,), ``positions`` (n, 3), ``points`` (m, 3),
    ``visibility_s`` (seconds to compute or load the matrix).
    """
    from camplace.instance import resolve_instance
    from camplace.pipeline import event_weights, resolve_settings, sampling_stage
    from camplace.visibility.stages import visibility_stage

    inst = resolve_instance("comet-flyby", seed=seed)
    s = resolve_settings(inst, seed=seed, candidates=positions, points=points)
    cands, pts = sampling_stage(inst, s)
    t = time.perf_counter()
    vis = visibility_stage(inst, cands, pts, cache=True)
    return {"matrix": vis.pattern, "weights": event_weights(vis.points, inst, s.event_mode),
            "positions": cands.positions, "points": vis.points.positions, "visibility_s": time.perf_counter() - t}


if __name__ == "__main__":  # cache the ladder's matrices: python benchmarks/flyby_ladder.py [positions ...]
    import sys

    for n in [int(a) for a in sys.argv[1:]] or LADDER_POSITIONS:
        got = flyby_inputs(n)
        print(n, got["matrix"].shape, got["matrix"].nnz, f"{got['visibility_s']:.1f} s", flush=True)
