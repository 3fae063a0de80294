"""The kernel list compiled into the wheel (tools/jit_cache.py) matches the code.

``pip install .`` compiles the signatures in ``tools/jit_signatures.txt`` so that a user's first run
loads machine code instead of compiling it. A kernel renamed or moved, or called with new argument
types, silently falls back to compiling on first use; these tests catch that.
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import jit_cache  # noqa: E402

# in a subprocess: the README's quick start at a reduced size, then every camplace kernel's
# signatures called from Python (a kernel loaded from the cache still records its signature)
_DUMP = """
import json, sys, tempfile
from numba.core.registry import CPUDispatcher
from camplace.cli import main
with tempfile.TemporaryDirectory() as tmp:
    assert main(["run", "comet-67p-bunker", "-o", tmp + "/q", "--candidates", "150", "--points", "1500",
                 "--no-cache"]) == 0
used = sorted({f"{n}:{a}\\t{s!r}" for n, m in list(sys.modules.items()) if n.startswith("camplace.")
               for a, o in vars(m).items() if isinstance(o, CPUDispatcher) and o.__module__ == n
               for s in o.signatures})
print("SIGS" + json.dumps(used))
"""


def test_every_recorded_kernel_exists_and_its_signatures_read_back():
    table = jit_cache.read_signatures()
    assert len(table) >= 20, "the list lost most of its kernels"
    for (module, qualname), sigs in table.items():
        obj = importlib.import_module(module)
        for part in qualname.split("."):
            obj = getattr(obj, part)
        assert hasattr(obj, "compile"), f"{module}:{qualname} is not a numba kernel"
        for sig in sigs:
            assert isinstance(jit_cache.parse_signature(sig), tuple), sig


def test_quick_start_calls_no_kernel_signature_missing_from_the_list(tmp_path):
    proc = subprocess.run([sys.executable, "-c", _DUMP], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("SIGS"))
    used = json.loads(line[4:])
    assert len(used) >= 10, used  # the quick start calls the presolve, bound and search kernels
    listed = {f"{m}:{q}\t{s}" for (m, q), sigs in jit_cache.read_signatures().items() for s in sigs}
    missing = [u for u in used if u not in listed]
    assert not missing, "run 'python tools/jit_cache.py record': missing " + "; ".join(missing)


def test_build_compiles_a_package_copy_so_a_fresh_process_loads_instead_of_compiling(tmp_path):
    """``build`` on a copy of the package: afterwards the quick start's kernels load from the copy's cache."""
    import shutil

    src = Path(importlib.import_module("camplace").__file__).parent
    shutil.copytree(src, tmp_path / "camplace", ignore=shutil.ignore_patterns("__pycache__"))
    one = {k: v for k, v in jit_cache.read_signatures().items() if k[0] == "camplace.visibility._kernels"}
    assert one, "the list has no visibility kernel"
    listing = tmp_path / "one.txt"
    listing.write_text("\n".join(f"{m}:{q}\t{s}" for (m, q), sigs in one.items() for s in sigs), encoding="utf-8")
    (tmp_path / "claims").mkdir()
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "jit_cache.py"), "_worker", str(tmp_path), str(listing),
                           str(tmp_path / "claims")], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and f"compiled {sum(map(len, one.values()))}" in proc.stdout, proc.stdout + proc.stderr
    cached = list((tmp_path / "camplace" / "visibility" / "__pycache__").glob("_kernels.*.nbc"))
    assert len(cached) >= len(one), cached
    # a fresh process finds every listed signature in the copy's cache (numba's own lookup)
    check = (
        "import sys; sys.path.insert(0, sys.argv[1]); sys.path.insert(0, sys.argv[2]); import jit_cache\n"
        "from numba.core.registry import cpu_target\n"
        "import camplace.visibility._kernels as K\n"
        "ctx = cpu_target.target_context\n"
        "for (m, q), sigs in jit_cache.read_signatures().items():\n"
        "    if m != 'camplace.visibility._kernels': continue\n"
        "    for s in sigs:\n"
        "        d = getattr(K, q); sig = jit_cache.parse_signature(s)\n"
        "        assert d._cache.load_overload(sig, ctx) is not None, (q, s)\n"
        "print('ok', K.__file__)\n"
    )
    proc = subprocess.run([sys.executable, "-c", check, str(tmp_path), str(ROOT / "tools")], capture_output=True,
                          text=True, timeout=300, env={k: v for k, v in __import__("os").environ.items()
                                                       if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert str(tmp_path) in proc.stdout


def test_workers_share_one_list_and_each_kernel_is_compiled_once(tmp_path):
    """The build's workers take kernels from one list as each frees up: whichever comes to a kernel
    first claims it, so every kernel is taken exactly once, whatever the interleaving."""
    claims = tmp_path / "claims"
    claims.mkdir()
    takers = [jit_cache._claim(claims) for _ in range(3)]
    taken: dict[int, int] = {}
    rng = __import__("random").Random(4)
    for i in range(40):
        for w in rng.sample(range(3), 3):  # each worker comes to kernel i, in a random order
            if takers[w](i):
                assert i not in taken
                taken[i] = w
    assert sorted(taken) == list(range(40))
    assert len(set(taken.values())) > 1
