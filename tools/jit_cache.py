"""Compile camplace's numba kernels when the package is built, so that a user's first run does not.

numba caches compiled kernels beside their source files (``__pycache__/*.nbi``, ``*.nbc``), keyed by
the source file's content hash, the numba and Python versions and the host CPU. ``pip install .``
builds the wheel on the machine it installs on, so kernels compiled into the build folder are valid
in the installed package: ``setup.py`` runs ``python tools/jit_cache.py build BUILD_LIB`` after
copying the sources, and the cache files travel in the wheel. Where anything differs (another numba,
another CPU, a wheel built elsewhere) numba finds no matching entry and compiles on first use as
before, so this step can only save time, never change a result.

Two sub-commands:

``build BUILD_LIB``
    Compile every kernel signature listed in ``tools/jit_signatures.txt`` inside the package copy
    at ``BUILD_LIB`` (one worker process per allowed core, each taking the next whole kernel of one list as it frees up). Needs only
    numba, numpy and scipy (the build requirements); a module that cannot be imported there is
    skipped with a note. Never fails the build: it prints what it compiled and exits 0.
``record``
    Run the verbs a user runs (every built-in, every mode, at reduced sizes, plus the README's
    quick start at full size) in this process and write the signatures every camplace kernel was
    called with to ``tools/jit_signatures.txt``. Run it after changing a kernel's name, module or
    argument types; ``tests/test_jit_cache.py`` fails when the list misses a signature that the
    quick start uses.

The list's format: one line per signature, ``module:qualname<TAB>repr(signature)``, where the repr
is what ``eval`` reads back in the namespace of ``numba.core.types``.
"""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
import types as pytypes
from pathlib import Path
from typing import Callable

HERE = Path(__file__).resolve().parent
SIGNATURES = HERE / "jit_signatures.txt"
PACKAGE = "camplace"


def read_signatures(path: Path = SIGNATURES) -> dict[tuple[str, str], list[str]]:
    """The recorded signatures.

    Returns
    -------
    dict of (module, qualname) to list of str
        Signature reprs per kernel, in file order.
    """
    out: dict[tuple[str, str], list[str]] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, sig = line.split("\t", 1)
        module, qualname = name.split(":", 1)
        out.setdefault((module, qualname), []).append(sig)
    return out


def parse_signature(text: str):
    """A signature repr (``(Array(float32, 1, 'C', False, aligned=True), int64)``) as numba types."""
    from numba.core import types

    return eval(text, {"__builtins__": {}}, dict(vars(types)))  # noqa: S307 - our own recorded file


def _stub_packages(build_lib: Path, modules: list[str]) -> None:
    """Make the packages above ``modules`` importable without running their ``__init__``.

    A package's ``__init__`` may import what the build environment lacks (OR-Tools, trimesh); the
    kernels' modules need only their own imports.
    """
    for module in modules:
        parts = module.split(".")[:-1]
        for i in range(1, len(parts) + 1):
            name = ".".join(parts[:i])
            if name in sys.modules:
                continue
            stub = pytypes.ModuleType(name)
            stub.__path__ = [str(build_lib.joinpath(*parts[:i]))]
            sys.modules[name] = stub


def compile_kernels(build_lib: Path, kernels: list[tuple[str, str, list[str]]],
                    take: Callable[[int], bool] | None = None) -> tuple[int, list[str]]:
    """Compile the given kernels of the package copy at ``build_lib`` into its ``__pycache__``.

    Parameters
    ----------
    build_lib : Path
        The folder that holds the ``camplace`` package copy.
    kernels : list of (module, qualname, signature reprs)
    take : callable, optional
        ``take(i)``: whether to compile kernel ``i`` (default: every one); :func:`_claim`'s, so
        that parallel workers share one list.

    Returns
    -------
    compiled : int
        Signatures compiled (or found already cached).
    skipped : list of str
        One note per kernel that could not be compiled, with the reason.
    """
    os.environ.pop("NUMBA_CACHE_DIR", None)  # the cache must land beside the sources
    sys.path.insert(0, str(build_lib))
    _stub_packages(build_lib, sorted({m for m, _, _ in kernels}))
    compiled, skipped = 0, []
    for i, (module, qualname, sigs) in enumerate(kernels):
        if take is not None and not take(i):
            continue
        try:
            obj = importlib.import_module(module)
            for part in qualname.split("."):
                obj = getattr(obj, part)
            for sig in sigs:
                obj.compile(parse_signature(sig))
                compiled += 1
        except Exception as exc:  # noqa: BLE001 - a build step that only saves time never fails the build
            skipped.append(f"{module}:{qualname}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    return compiled, skipped


def _allowed_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def build(build_lib: Path, workers: int | None = None) -> int:
    """Compile every recorded kernel into ``build_lib``, in parallel worker processes.

    Each worker takes whole kernels (numba keeps one index file per kernel, so no two processes
    write the same file). Prints one summary line; returns 0 whatever happened.
    """
    if not SIGNATURES.is_file():
        print(f"camplace: no {SIGNATURES.name}; kernels compile on first use")
        return 0
    try:
        import numba  # noqa: F401
    except ImportError:
        print("camplace: numba is not in the build environment; kernels compile on first use")
        return 0
    table = read_signatures()
    # most signatures first: the longest compiles start first, the short ones fill in at the end
    kernels = sorted(((m, q, s) for (m, q), s in table.items()), key=lambda t: -len(t[2]))
    workers = max(1, min(workers or _allowed_cores(), len(kernels)))
    t0 = time.perf_counter()
    fh = tempfile.NamedTemporaryFile("w", suffix=".txt", delete=False, encoding="utf-8")
    fh.write("\n".join(f"{m}:{q}\t{s}" for m, q, sigs in kernels for s in sigs))
    fh.close()
    claims = tempfile.mkdtemp(prefix="camplace-jit-")
    procs = [subprocess.Popen([sys.executable, __file__, "_worker", str(build_lib), fh.name, claims],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for _ in range(workers)]
    compiled, notes = 0, []
    for proc in procs:
        out, _ = proc.communicate()
        lines = out.strip().splitlines()
        for line in lines:
            if line.startswith("compiled "):
                compiled += int(line.split()[1])
            elif line.startswith("skipped "):
                notes.append(line[len("skipped "):])
        if proc.returncode != 0:
            notes.append(f"worker exited {proc.returncode}: {lines[-1] if lines else ''}")
    os.unlink(fh.name)
    shutil.rmtree(claims, ignore_errors=True)
    print(f"camplace: compiled {compiled} kernel signatures in {time.perf_counter() - t0:.1f} s "
          f"({workers} processes){'; skipped: ' + '; '.join(notes) if notes else ''}")
    return 0


def _claim(claims: Path) -> Callable[[int], bool]:
    """``take(i)``: whether this worker compiles kernel ``i`` of the list, decided as it comes to
    it: the first worker to make the kernel's claim folder does (no fixed shares, so a worker that
    drew long compiles does not keep the others waiting at the end)."""
    def take(i: int) -> bool:
        try:
            os.mkdir(claims / str(i))
        except FileExistsError:
            return False
        return True

    return take


def _worker(build_lib: Path, listing: Path, claims: Path) -> int:
    table = read_signatures(listing)
    compiled, skipped = compile_kernels(build_lib, [(m, q, s) for (m, q), s in table.items()], _claim(claims))
    print(f"compiled {compiled}")
    for note in skipped:
        print(f"skipped {note}")
    return 0


# The verbs whose kernels are recorded: (argv, ...) run in one process by ``record``. Reduced sizes
# give the same argument types as full ones; the quick start runs at its full size as the README
# gives it.
RECORD_RUNS: tuple[tuple[str, ...], ...] = (
    ("run", "comet-67p-bunker", "-o", "{tmp}/quick"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/mv", "--mode", "multiview", "--candidates", "200", "--points", "2000"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/ang", "--mode", "multiview", "--min-angle", "20",
     "--candidates", "200", "--points", "2000"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/v3", "--mode", "multiview", "--views", "3", "--k", "6",
     "--candidates", "200", "--points", "2000"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/sc", "--mode", "setcover", "--candidates", "200", "--points", "2000"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/q", "--mode", "quality", "--candidates", "200", "--points", "2000"),
    # small runs with a report take other routes (the report's campaigns and comparisons score on
    # a float64 CSR: the dense quality tree, the angle engine's small-model kernels)
    ("run", "comet-67p-bunker", "-o", "{tmp}/r60", "--candidates", "60", "--points", "600", "--report",
     "--report-systems", "3"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/q60", "--mode", "quality", "--candidates", "60", "--points", "600",
     "--report", "--report-systems", "3"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/mv60", "--mode", "multiview", "--candidates", "60", "--points", "600",
     "--report", "--report-systems", "3"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/ang60", "--mode", "multiview", "--min-angle", "20",
     "--candidates", "60", "--points", "600", "--report", "--report-systems", "3"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/sc60", "--mode", "setcover", "--candidates", "60", "--points", "600",
     "--report", "--report-systems", "3"),
    ("run", "comet-67p-bunker", "-o", "{tmp}/k6", "--k", "6", "--candidates", "200", "--points", "2000"),
    # multiview with a fixed camera: the angle engine at 0 degrees with its fixed-camera kernels
    ("run", "comet-67p-bunker", "-o", "{tmp}/mvf", "--mode", "multiview", "--fixed", "3", "--candidates", "200",
     "--points", "2000"),
    # a binary run with a plan: the planner reads the bitsets (visibility.bits.column_sums)
    ("run", "comet-flyby", "-o", "{tmp}/fly", "--candidates", "200", "--points", "2000", "--phases", "3", "--speed", "5"),
    ("run", "volcanic-eruption", "-o", "{tmp}/vol", "--candidates", "200", "--points", "2000"),
    ("run", "comet-67p-team", "-o", "{tmp}/team", "--candidates", "60", "--points", "600"),
    # a robust p10 run: the stacked scenario bits' kernels (robust.kernels, visibility.bits.row_range)
    ("run", "comet-67p-bunker", "-o", "{tmp}/p10", "--candidates", "60", "--points", "600", "--pose-error", "0.1,5",
     "--scenarios", "4", "--robust-objective", "p10"),
)


# What a Python caller passes the solver (docs/api.md): the run folder's float32 matrix, its bool
# pattern, and the float64 CSR that scipy makes by default (a user's own matrix), in every mode and
# with the side options; each tuple is solve()'s keywords. A float64 matrix took a fresh install
# 10.6 s of compiling in four calls that then take 0.8 s.
RECORD_API: tuple[dict, ...] = (
    {"mode": "maxcover", "k": 3},
    {"mode": "quality", "k": 3},
    {"mode": "multiview", "k": 3},
    {"mode": "multiview", "k": 3, "min_angle_deg": 20.0},
    {"mode": "multiview", "k": 3, "fixed": (1,)},
    {"mode": "setcover"},
    {"mode": "setcover", "required_fraction": 0.9},
    {"mode": "maxcover", "k": 3, "fixed": (1,), "forbidden": (2,)},
    {"mode": "quality", "k": 3, "fixed": (1,)},
    {"mode": "maxcover", "k": 3, "min_distance_m": 2.0},
)


def _api_all(folder: Path) -> None:
    """:data:`RECORD_API` on the run folder's matrix as a caller of ``camplace.solver.solve`` has it."""
    import numpy as np

    from camplace.runfolder import RunFolder
    from camplace.solver import solve

    run = RunFolder(folder)
    w = run.weights()
    geometry = {"positions": run.candidates.positions, "points": run.points.positions}
    graded = run.matrix.copy()
    graded.data = np.linspace(0.2, 1.0, graded.nnz, dtype=np.float32)  # qualities, not only ones
    for matrix in (run.matrix, run.pattern, run.matrix.astype(np.float64), graded, graded.astype(np.float64)):
        for kw in RECORD_API:
            solve(matrix, w, **kw, **geometry)


def _run_all() -> None:
    from camplace.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        for argv in RECORD_RUNS:
            code = main([a.format(tmp=tmp) for a in argv] + ["--no-cache"])
            if code != 0:
                raise SystemExit(f"camplace {' '.join(argv)} exited {code}")
        _api_all(Path(tmp) / "q60")


def record(out: Path = SIGNATURES) -> int:
    """Run :data:`RECORD_RUNS` and write the signatures camplace's kernels were called with from Python.

    A first process runs them to fill numba's cache; this process then runs them again, loading
    every kernel from the cache, so only the kernels Python calls hold signatures (a kernel called
    from another compiles with its caller), and the list does not depend on what was cached before.
    """
    from numba.core.registry import CPUDispatcher

    subprocess.run([sys.executable, __file__, "_warm"], check=True, stdout=subprocess.DEVNULL)
    _run_all()
    lines = set()
    for name, module in list(sys.modules.items()):
        if not name.startswith(PACKAGE + "."):
            continue
        for attr, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == name:
                for sig in obj.signatures:
                    try:
                        parse_signature(repr(sig))  # must read back
                    except Exception:
                        print(f"unreadable signature {name}:{attr} {sig!r}")
                        continue
                    lines.add(f"{name}:{attr}\t{sig!r}")
    header = ("# numba kernel signatures compiled when the package is built (tools/jit_cache.py);\n"
              "# written by 'python tools/jit_cache.py record'\n")
    out.write_text(header + "\n".join(sorted(lines)) + "\n", encoding="utf-8")
    print(f"wrote {len(lines)} signatures to {out}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) >= 2 and sys.argv[1] == "build" and len(sys.argv) == 3:
        raise SystemExit(build(Path(sys.argv[2]).resolve()))
    if len(sys.argv) == 5 and sys.argv[1] == "_worker":
        raise SystemExit(_worker(Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4])))
    if sys.argv[1:] == ["record"]:
        raise SystemExit(record())
    if sys.argv[1:] == ["_warm"]:
        raise SystemExit(_run_all())
    raise SystemExit("usage: python tools/jit_cache.py build BUILD_LIB | record")
