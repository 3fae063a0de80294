"""A run folder (the ``-o`` folder of ``camplace run``): one reader and one writer for its files.

======================  ===============================================================
``instance.toml``       the instance as run (:func:`camplace.instance.save_instance`)
``solution.json``       the answer (:class:`camplace.solution.Solution`), written last
``candidates.csv``      the candidate poses, one matrix column each (``CandidateSet``)
``points.csv``          the target points, one matrix row each (``TargetPoints``)
``visibility.cpm``      the points x candidates matrix (:mod:`camplace.visibility.store`;
                        ``visibility.npz`` when run with ``--matrix-format npz``)
======================  ===============================================================

:class:`RunFolder` reads each file on first use only (a verb reads what it needs), checks the
sizes against each other, and writes each file atomically. Importing this module loads neither
Embree, nor numba, nor OpenCV, nor OR-Tools; reading the matrix loads the store's numba decoding
kernels, reading the instance loads trimesh without its optional Embree ray interface
(:func:`camplace._lazy.import_trimesh`).
"""

from __future__ import annotations

import warnings
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from camplace.errors import CamplaceError

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    import scipy.sparse as sp

    from camplace.instance import Instance
    from camplace.sampling import CandidateSet
    from camplace.solution import Solution
    from camplace.visibility.points import TargetPoints

__all__ = ["RunFolder", "read_csv_columns"]

INSTANCE_NAME = "instance.toml"
SOLUTION_NAME = "solution.json"
CANDIDATES_NAME = "candidates.csv"
POINTS_NAME = "points.csv"


def read_csv_columns(path: Path, columns: Sequence[str]) -> dict[str, "np.ndarray"]:
    """The named columns of a CSV file with a header line, as float64 arrays (numpy's C parser).

    Parameters
    ----------
    path : Path
    columns : sequence of str
        Header names to read.

    Returns
    -------
    dict of str to (rows,) float64

    Raises
    ------
    CamplaceError
        When the file cannot be read, lacks a column or holds something that is not a number.
    """
    import numpy as np

    try:
        with open(path, encoding="utf-8") as fh:
            header = [h.strip() for h in fh.readline().strip().split(",")]
            missing = [c for c in columns if c not in header]
            if missing:
                raise CamplaceError(f"{path}: missing column(s) {', '.join(missing)}")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data"
                data = np.loadtxt(fh, delimiter=",", usecols=[header.index(c) for c in columns], ndmin=2,
                                  dtype=np.float64)
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise CamplaceError(f"{path}: bad number ({exc})") from None
    if data.size == 0:
        data = np.zeros((0, len(columns)))
    return {c: np.ascontiguousarray(data[:, t]) for t, c in enumerate(columns)}


class RunFolder:
    """The files of one run folder, read lazily and written atomically.

    Parameters
    ----------
    path : path
        The folder; or its matrix file (``visibility.cpm`` / ``.npz``, as ``camplace solve``
        accepts), whose folder is then the run folder.

    Attributes
    ----------
    path : Path
        The folder.
    solution_record : dict
        ``solution.json`` as stored (read on first use).
    solution : Solution
        The same as a :class:`~camplace.solution.Solution` (without candidates and matrix).
    instance : Instance
        ``instance.toml``.
    candidates : CandidateSet
        ``candidates.csv`` (n columns).
    points : TargetPoints
        ``points.csv`` (m rows).
    matrix : (m, n) scipy.sparse.csr_matrix of float32
        ``visibility.cpm`` or ``visibility.npz`` (:func:`camplace.visibility.store.load_visibility`).
    pattern : (m, n) scipy.sparse.csr_matrix of bool, or of float32
        The matrix as the solver takes it: a binary matrix (every value 1) with bool data, read
        without a float copy (``load_visibility(..., pattern=True)``); a graded one as ``matrix``.

    Every attribute raises :class:`~camplace.errors.CamplaceError` (one line naming the file and
    the fix) when its file is missing or unreadable, or disagrees with what is already read.

    Examples
    --------
    >>> run = RunFolder("out")                          # doctest: +SKIP
    >>> run.matrix.shape, run.solution.objective        # reads the matrix and solution.json only
    """

    def __init__(self, path: str | Path) -> None:
        p = Path(path)
        self._matrix_file = p if p.is_file() else None
        self.path = p.parent if p.is_file() else p

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    def file(self, name: str) -> Path:
        """The path of file ``name`` in the folder (whether or not it exists)."""
        return self.path / name

    def has(self, name: str) -> bool:
        """True when file ``name`` is in the folder."""
        return (self.path / name).is_file()

    def has_matrix(self) -> bool:
        """True when the folder holds a matrix file (``visibility.cpm`` or ``visibility.npz``)."""
        from camplace.visibility.store import MATRIX_NAME, NPZ_NAME

        return self._matrix_file is not None or self.has(MATRIX_NAME) or self.has(NPZ_NAME)

    @property
    def matrix_path(self) -> Path:
        """The matrix file (``visibility.cpm``, else ``visibility.npz``, or the file given)."""
        from camplace.visibility.store import matrix_path

        return matrix_path(self._matrix_file or self.path)

    # -- reading ---------------------------------------------------------------------------------

    def _require_solution(self) -> Path:
        p = self.file(SOLUTION_NAME)
        if not p.is_file():
            raise CamplaceError(f"{self.path}: no solution.json here (give the -o folder of 'camplace run')")
        return p

    @cached_property
    def solution_record(self) -> dict[str, Any]:
        from camplace._io import read_json

        data = read_json(self._require_solution(), SOLUTION_NAME, "solution")
        if not isinstance(data, dict):
            raise CamplaceError(f"{self.file(SOLUTION_NAME)}: cannot read the solution (not a JSON object; re-run)")
        return data

    @cached_property
    def solution(self) -> "Solution":
        from camplace.solution import Solution

        return Solution.from_dict(self.solution_record)

    @cached_property
    def instance(self) -> "Instance":
        from camplace._lazy import import_trimesh
        from camplace.instance import load_instance

        p = self.file(INSTANCE_NAME)
        if not p.is_file():
            raise CamplaceError(f"{self.path}: no instance.toml here (re-run 'camplace run ... -o {self.path}')")
        import_trimesh()  # a run folder's meshes are files, read with trimesh: without Embree
        return load_instance(p)

    @cached_property
    def candidates(self) -> "CandidateSet":
        from camplace.sampling.candidates import CandidateSet

        cands = CandidateSet.load(self.file(CANDIDATES_NAME))
        if "matrix" in self.__dict__ and len(cands) != self.matrix.shape[1]:
            raise CamplaceError(f"{self.file(CANDIDATES_NAME)}: {len(cands)} candidates but the matrix has "
                                f"{self.matrix.shape[1]} columns (re-run)")
        if cands.model is not None and self.file(INSTANCE_NAME).is_file():
            # a team's columns: check the models against the instance and add the zone membership
            team = getattr(self.instance, "team", None)
            n_models = len(self.instance.cameras)
            if team is None or (len(cands) and int(cands.model.max()) >= n_models):
                raise CamplaceError(f"{self.file(CANDIDATES_NAME)}: column model names camera models the instance.toml "
                                    f"beside it does not have ({n_models}) (re-run)")
            from camplace.sampling.candidates import CandidateSet as _C

            cands = _C(cands.positions, cands.aims, cands.rotations, sampler=cands.sampler, seed=cands.seed,
                       model=cands.model, zones=team.zone_membership(cands.positions))
        return cands

    @cached_property
    def points(self) -> "TargetPoints":
        from camplace.visibility.points import TargetPoints

        pts = TargetPoints.load(self.file(POINTS_NAME))
        if "matrix" in self.__dict__:
            self._check_rows(len(pts))
        return pts

    @cached_property
    def matrix(self) -> "sp.csr_matrix":
        from camplace.visibility.store import load_visibility

        matrix = load_visibility(self.matrix_path)
        if "points" in self.__dict__:
            self._check_rows(len(self.points), matrix)
        return matrix

    @cached_property
    def pattern(self) -> "sp.csr_matrix":
        from camplace.visibility.store import as_pattern_if_binary, load_visibility

        if "matrix" in self.__dict__:  # already read: share its index arrays
            return as_pattern_if_binary(self.matrix)
        matrix = load_visibility(self.matrix_path, pattern=True)
        if "points" in self.__dict__:
            self._check_rows(len(self.points), matrix)
        return matrix

    def _check_rows(self, n_rows: int, matrix=None) -> None:
        matrix = self.matrix if matrix is None else matrix
        if matrix.shape[0] != n_rows:
            raise CamplaceError(f"{self.path}: {self.matrix_path.name} has {matrix.shape[0]} rows but points.csv "
                                f"has {n_rows} (re-run)")

    def point_columns(self, columns: Sequence[str]) -> dict[str, "np.ndarray"]:
        """Columns of ``points.csv`` (e.g. ``x, y, z, weight``) without reading the rest (fast).

        Raises
        ------
        CamplaceError
            When points.csv is missing or lacks a column.
        """
        p = self.file(POINTS_NAME)
        if not p.is_file():
            raise CamplaceError(f"{p}: missing (the point weights are read from points.csv beside the matrix)")
        return read_csv_columns(p, columns)

    def candidate_positions(self) -> "np.ndarray | None":
        """(n, 3) float64 candidate positions from ``candidates.csv``, or None without that file (fast)."""
        import numpy as np

        p = self.file(CANDIDATES_NAME)
        if not p.is_file():
            return None
        c = read_csv_columns(p, ["x", "y", "z"])
        return np.column_stack([c["x"], c["y"], c["z"]])

    def check_sizes(self) -> None:
        """Check that the matrix matches solution.json's ``n_points`` x ``n_candidates``, points.csv and
        candidates.csv (reads all four)."""
        sol = self.solution
        shape = self.matrix.shape
        if shape != (sol.n_points, sol.n_candidates):
            raise CamplaceError(f"{self.matrix_path}: shape {shape} but solution.json says {sol.n_points} points x "
                                f"{sol.n_candidates} candidates (re-run)")
        if len(self.candidates) != sol.n_candidates:
            raise CamplaceError(f"{self.file(CANDIDATES_NAME)}: {len(self.candidates)} candidates but solution.json "
                                f"says {sol.n_candidates} (re-run)")
        self._check_rows(len(self.points))

    def require_cameras(self) -> None:
        """Stop when the solution chose no camera (nothing to validate, export or report)."""
        if not self.solution.cameras:
            raise CamplaceError(f"{self.file(SOLUTION_NAME)}: the solution has no cameras (the run found no camera system)")

    def weights(self, event_mode: str | None = None) -> "np.ndarray":
        """(m,) float64 row weights the run's solver maximised (:func:`camplace.event.event_weights`).

        ``event_mode`` defaults to the run's (``solution.json``), else ``all``.
        """
        from camplace.event import event_weights

        mode = event_mode or self.solution_record.get("event_mode") or "all"
        return event_weights(self.points, self.instance, mode) if mode != "all" else self.points.weight

    # -- writing ---------------------------------------------------------------------------------

    def save_instance(self, instance: "Instance") -> None:
        """Write ``instance.toml`` (and its mesh files beside it)."""
        from camplace.instance import save_instance

        self.path.mkdir(parents=True, exist_ok=True)
        save_instance(instance, self.file(INSTANCE_NAME), mesh_files=True)
        self.__dict__["instance"] = instance

    def save_candidates(self, candidates: "CandidateSet") -> None:
        """Write ``candidates.csv`` atomically."""
        candidates.save(self.file(CANDIDATES_NAME))
        self.__dict__["candidates"] = candidates

    def save_points(self, points: "TargetPoints") -> None:
        """Write ``points.csv`` atomically."""
        points.save(self.file(POINTS_NAME))
        self.__dict__["points"] = points

    def save_matrix(self, matrix, *, fmt: str = "cpm", link_from: str | Path | None = None,
                    meta: dict | None = None) -> Path:
        """Write the matrix (:func:`camplace.visibility.store.save_matrix`: ``visibility.cpm``, a hard
        link to ``link_from`` when possible, or ``visibility.npz``) atomically; returns the file."""
        from camplace.visibility.store import save_matrix

        self._matrix_file = None
        path = save_matrix(self.path, matrix, fmt=fmt, link_from=link_from, meta=meta)
        self.__dict__.pop("matrix", None)
        self.__dict__.pop("pattern", None)
        return path

    def save_visibility(self, visibility, fmt: str = "cpm") -> Path:
        """Write a :class:`~camplace.visibility.VisibilityMatrix`'s matrix (with its pair counts; a
        hard link to its cache entry when possible) atomically; returns the file. ``points.csv``
        is :meth:`save_points`."""
        self._matrix_file = None
        path = visibility.save_matrix(self.path, fmt)
        self.__dict__.pop("matrix", None)
        self.__dict__.pop("pattern", None)
        return path

    def save_solution(self, solution: "Solution | dict[str, Any]") -> None:
        """Write ``solution.json`` atomically (a :class:`Solution` or its record). Write it last:
        its presence means the run's outputs are complete."""
        from camplace._io import write_json_atomic

        record = solution if isinstance(solution, dict) else solution.to_dict()
        self.path.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.file(SOLUTION_NAME), record)
        self.__dict__["solution_record"] = record
        self.__dict__.pop("solution", None)
