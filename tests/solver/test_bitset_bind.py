"""The bitset engine's search kernel is loaded before the kernels that share its helpers
(:func:`camplace.solver.engines.bitset.search.bind_search_kernel`), with the argument types the
search calls it with: a run adds no second compiled signature (which would compile the kernel
again on a user's first run, instead of loading it)."""

import json
import subprocess
import sys

_CHILD = """
import json
from camplace.solver.engines.bitset import search as S
S.bind_search_kernel()
first = [str(s) for s in S._dfs_roots_block.signatures]
S.bind_search_kernel()  # a second call does nothing
again = [str(s) for s in S._dfs_roots_block.signatures]
from camplace.pipeline import run
sol = run("comet-67p-bunker", candidates=400, points=4000, cache=False, threads=2)
print(json.dumps({"first": first, "again": again, "after": [str(s) for s in S._dfs_roots_block.signatures],
                  "evals": sol.solver_stats["engine_stats"].get("bound_evaluations", 0),
                  "rounds": sol.solver_stats["engine_stats"].get("rounds", 0), "status": sol.status}))
"""


def test_the_bound_search_kernel_is_the_one_a_solve_calls() -> None:
    out = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True, timeout=600, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(got["first"]) == 1 and got["again"] == got["first"]
    assert got["rounds"] > 0 and got["evals"] > 0  # the search ran its roots through the kernel
    assert got["after"] == got["first"], got  # with the types bind_search_kernel used
    assert got["status"] == "optimal"
