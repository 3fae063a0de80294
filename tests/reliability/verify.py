"""Checks that every output file a run left behind is complete (parses whole, sizes agree)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from camplace.instance import load_instance
from camplace.visibility.store import load_visibility

from .counts import COUNTS

KNOWN = ("solution.json", "candidates.csv", "points.csv", "visibility.cpm", "light_curves.csv", "scene.ply", "instance.toml")


def verify_outputs(outdir: Path) -> int:
    """Assert each existing output is complete and mutually consistent; return how many were checked."""
    outdir = Path(outdir)
    leftovers = [p.name for p in outdir.iterdir() if p.name.startswith(".") and ".tmp" in p.name] if outdir.exists() else []
    assert not leftovers, f"temporary files left behind: {leftovers}"
    n = 0
    shape = None
    if (outdir / "visibility.cpm").exists():
        shape = load_visibility(outdir / "visibility.cpm").shape
        n += 1
    if (outdir / "candidates.csv").exists():
        c = np.loadtxt(outdir / "candidates.csv", delimiter=",", skiprows=1, ndmin=2)
        assert c.shape[1] == 16 and np.all(np.isfinite(c)) and np.array_equal(c[:, 0], np.arange(len(c)))
        if shape is not None:
            assert len(c) == shape[1]
        n += 1
    if (outdir / "points.csv").exists():
        p = np.loadtxt(outdir / "points.csv", delimiter=",", skiprows=1, ndmin=2)
        assert p.shape[1] == 9 and np.array_equal(p[:, 0], np.arange(len(p)))
        assert abs(p[:, 8].sum() - 1.0) < 1e-9
        if shape is not None:
            assert len(p) == shape[0]
        n += 1
    if (outdir / "light_curves.csv").exists():
        lc = np.loadtxt(outdir / "light_curves.csv", delimiter=",", skiprows=1, ndmin=2)
        assert lc.shape[1] == 6 and np.all(np.isfinite(lc))
        n += 1
    if (outdir / "scene.ply").exists():
        mesh = trimesh.load(outdir / "scene.ply", force="mesh", process=False)
        assert len(mesh.faces) > 0
        n += 1
    if (outdir / "instance.toml").exists():
        load_instance(outdir / "instance.toml")
        n += 1
    if (outdir / "solution.json").exists():
        sol = json.loads((outdir / "solution.json").read_text())
        assert len(sol["cameras"]) == sol["k"] and sol["bound"] >= sol["objective"] - 1e-9
        # solution.json is written last: everything else must be there
        for name in KNOWN:
            assert (outdir / name).exists(), name
        n += 1
    COUNTS["outputs verified"] += n
    return n
