"""On-disk cache of visibility matrices, keyed by a content hash of everything that determines them.

The key hashes the engine version and the task's arrays (row points, normals, frames, lit mask,
candidate poses, intrinsics, quality settings and every frame's triangles exactly as cast), so
any change of instance, candidates or settings gives a new key. Entries are ``.cpm`` files of
:mod:`camplace.visibility.store` (the engine's pair counts in their ``meta``), the same format as
a run folder's ``visibility.cpm``, which is a hard link to the entry when the two share a file
system (one copy on disk). Entries are written atomically (temp file + rename): an interrupted
run leaves no corrupt entry, and an unreadable entry is treated as a miss and rewritten.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.visibility.chunk import ENGINE_VERSION

log = logging.getLogger(__name__)


def default_cache_dir() -> Path:
    """``$CAMPLACE_CACHE_DIR``, else ``$XDG_CACHE_HOME/camplace``, else ``~/.cache/camplace``."""
    env = os.environ.get("CAMPLACE_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "camplace"


def task_key(task) -> str:
    """Hex SHA-256 of a :class:`~camplace.visibility.chunk.VisibilityTask`'s content."""
    h = hashlib.sha256()
    h.update(f"camplace-visibility-{ENGINE_VERSION}".encode())
    scalars = {
        "width_px": task.width_px, "height_px": task.height_px, "near_m": task.near_m, "far_m": task.far_m,
        "graded": task.graded, "required_px_per_m": task.required_px_per_m, "cos_max": task.cos_max_incidence,
    }
    if task.min_target_px > 0:  # only when set: the keys of matrices without it stay as they were
        scalars["min_target_px"] = task.min_target_px
    if task.quantised:  # a graded matrix kept as bytes (float32 entries keep their keys)
        scalars["quantised"] = "byte"
    h.update(json.dumps(scalars, sort_keys=True).encode())
    for name in ("positions", "normals", "frame", "active", "eps_m", "cam_positions", "cam_rotations", "K"):
        a = np.ascontiguousarray(getattr(task, name))
        h.update(f"{name}{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    if task.cam_model is not None:  # a team: per-column models (single-model keys stay as they were)
        h.update(b"cam_model")
        h.update(np.ascontiguousarray(task.cam_model, dtype=np.int16).tobytes())
        for K, w, hh, near, far in task.models:
            h.update(np.ascontiguousarray(K, dtype=np.float64).tobytes())
            h.update(json.dumps([int(w), int(hh), float(near), float(far)]).encode())
    for f in sorted(task.scene_triangles):
        a = np.ascontiguousarray(task.scene_triangles[f], dtype=np.float32)
        h.update(f"frame{f}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def entry_path(cache_dir: Path, key: str) -> Path:
    return Path(cache_dir) / "visibility" / f"{key}.cpm"


def load(cache_dir: Path, key: str, shape: tuple[int, int], bits: bool = False,
         quantised: bool = False) -> tuple[sp.csr_matrix, dict] | None:
    """The cached matrix and stats, or None on a miss or an unreadable entry (then removed).

    With ``bits`` the matrix comes back as column bitsets
    (:class:`~camplace.visibility.bits.BitMatrix`, binary instances); with ``quantised`` as
    quantised columns (:class:`~camplace.visibility.qbytes.ByteMatrix`, graded instances kept as
    bytes)."""
    from camplace.visibility.store import load_bits, load_bytes, load_visibility, read_meta

    path = entry_path(cache_dir, key)
    if not path.exists():
        return None
    try:
        stats = read_meta(path).get("stats", {})
        matrix = load_bits(path) if bits else load_bytes(path) if quantised else load_visibility(path)
        if matrix.shape != shape:
            raise CamplaceError(f"shape {matrix.shape}, expected {shape}")
    except CamplaceError as exc:  # any unreadable entry is a miss
        log.warning("visibility cache: ignoring unreadable entry %s (%s)", path, exc)
        try:
            path.unlink()
        except OSError:
            pass
        return None
    log.info("visibility cache: hit %s", path)
    return matrix, stats


def store(cache_dir: Path, key: str, matrix: sp.csr_matrix, stats: dict) -> Path | None:
    """Write an entry atomically and return its path; a failure to write the cache is logged
    (None), never fatal."""
    from camplace.visibility.store import save_visibility

    path = entry_path(cache_dir, key)
    try:
        save_visibility(path, matrix, meta={"stats": stats})
    except OSError as exc:
        log.warning("visibility cache: could not write %s (%s)", path, exc)
        return None
    return path
