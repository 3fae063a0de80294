"""Candidate camera poses: positions from a sampler, each aimed at the event (OpenCV axes)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camplace._io import csv_text, read_numeric_csv, write_text_atomic
from camplace.errors import CamplaceError
from camplace.geometry import look_at
from camplace.sampling.samplers import sample_positions

CSV_HEADER = "index,x,y,z,aim_x,aim_y,aim_z," + ",".join(f"r{i}{j}" for i in range(1, 4) for j in range(1, 4))
#: ``candidates.csv`` of a team instance: one more column, the camera model's index in ``Instance.cameras``.
CSV_HEADER_TEAM = CSV_HEADER + ",model"


@dataclass(frozen=True, eq=False)
class CandidateSet:
    """Candidate camera poses; each is one column of the visibility matrix.

    Attributes
    ----------
    positions : (n, 3) float64
        Camera centres, metres.
    aims : (n, 3) float64
        The point each camera looks at.
    rotations : (n, 3, 3) float64
        World-from-camera rotations, OpenCV axes (x right, y down, z forward).
    sampler : str
    seed : int or None
    model : (n,) int16 or None
        A team's camera model of each column (index into ``Instance.cameras``); None for the
        single-model instances without a team (every column is model 0).
    zones : (n, z) bool or None
        Whether each column's camera centre lies in each of the team's ``[[zones]]``.
    """

    positions: np.ndarray
    aims: np.ndarray
    rotations: np.ndarray
    sampler: str = ""
    seed: int | None = None
    model: np.ndarray | None = None
    zones: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    def models(self) -> np.ndarray:
        """(n,) int16 model index of every column (zeros without a team)."""
        return np.zeros(len(self), dtype=np.int16) if self.model is None else np.asarray(self.model, dtype=np.int16)

    def with_run(self, sampler: str, seed: int | None) -> "CandidateSet":
        """The same poses (and models, zones) labelled with a run's sampler and seed."""
        return CandidateSet(self.positions, self.aims, self.rotations, sampler=sampler, seed=seed, model=self.model, zones=self.zones)

    def to_csv(self) -> str:
        """The ``candidates.csv`` text: ``index,x,y,z,aim_x,aim_y,aim_z,r11,...,r33`` (and ``,model`` for a team).

        Formatted once per set and kept (the poses are frozen): ``camplace run`` formats it while
        the rays are cast (:func:`camplace.pipeline.run_settings`), and the run folder writes it."""
        text = self.__dict__.get("_csv")
        if text is None:
            n = len(self)
            cols = [np.arange(n), *np.asarray(self.positions, dtype=np.float64).T,
                    *np.asarray(self.aims, dtype=np.float64).T, *np.asarray(self.rotations, dtype=np.float64).reshape(n, 9).T]
            if self.model is not None:
                cols.append(np.asarray(self.model, dtype=np.int64))
            text = self.__dict__["_csv"] = csv_text(CSV_HEADER if self.model is None else CSV_HEADER_TEAM, cols)
        return text

    def save(self, path: str | Path) -> None:
        """Write ``candidates.csv`` atomically."""
        write_text_atomic(path, self.to_csv())

    @classmethod
    def load(cls, path: str | Path) -> "CandidateSet":
        """Read a ``candidates.csv`` (as written by :meth:`save`); rotations must be orthonormal."""
        try:
            with Path(path).open() as fh:
                first = fh.readline().replace(" ", "").strip()
        except (OSError, UnicodeDecodeError):
            first = ""  # read_numeric_csv reports it
        team = first == CSV_HEADER_TEAM
        data = read_numeric_csv(path, CSV_HEADER_TEAM if team else CSV_HEADER, "candidates file")
        rot = data[:, 7:16].reshape(-1, 3, 3)
        err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(initial=0.0)
        if err > 1e-6:
            raise CamplaceError(f"{path}: rotation columns r11..r33 are not orthonormal (max error {err:.2g})")
        model = None
        if team:
            model = data[:, 16]
            if np.any(model != np.round(model)) or np.any(model < 0):
                raise CamplaceError(f"{path}: column model must hold whole numbers >= 0 (camera model indices)")
            model = model.astype(np.int16)
        return cls(positions=data[:, 1:4].copy(), aims=data[:, 4:7].copy(), rotations=rot.copy(), sampler="file", model=model)


def make_candidates(
    sampler: str,
    n: int,
    min_m: np.ndarray | tuple[float, float, float],
    max_m: np.ndarray | tuple[float, float, float],
    aims: np.ndarray,
    *,
    seed: int | np.random.SeedSequence | None = 0,
) -> CandidateSet:
    """Sample ``n`` camera positions in the volume; each becomes one pose per aim point.

    Parameters
    ----------
    sampler : {"chaotic", "uniform", "sobol"}
    n : int
        Positions.
    min_m, max_m : (3,) float64
    aims : (3,) or (a, 3) float64
        Point(s) each camera position looks at (e.g. the event centre, or key-frame target centres).
        Column ``i * a + j`` is position ``i`` aimed at ``aims[j]``.
    seed : int, SeedSequence or None

    Returns
    -------
    CandidateSet
        ``n * a`` poses.
    """
    positions = sample_positions(sampler, n, min_m, max_m, seed=seed)
    return candidates_from_positions(positions, aims, sampler=sampler, seed=seed if isinstance(seed, int) else None)


def candidates_from_positions(
    positions: np.ndarray, aims: np.ndarray, *, sampler: str = "", seed: int | None = None
) -> CandidateSet:
    """One pose per (position, aim): column ``i * a + j`` is position ``i`` aimed at ``aims[j]``.

    Parameters
    ----------
    positions : (n, 3) float64
    aims : (3,) or (a, 3) float64

    Returns
    -------
    CandidateSet
        ``n * a`` poses.
    """
    aims = np.atleast_2d(np.asarray(aims, dtype=np.float64))
    n = len(positions)
    positions = np.repeat(np.asarray(positions, dtype=np.float64), len(aims), axis=0)
    aim_cols = np.tile(aims, (n, 1))
    # a sample exactly at its aim point cannot be aimed; nudge it (probability ~0)
    same = np.linalg.norm(positions - aim_cols, axis=1) < 1e-9
    positions[same] += 1e-6
    return CandidateSet(positions=positions, aims=aim_cols, rotations=look_at(positions, aim_cols), sampler=sampler, seed=seed)
