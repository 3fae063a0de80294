"""A graded run end to end with its matrix quantised to bytes (issue 32): the run stores
``colbytes``, proves the optimum of the quantised values (checked by enumeration on the matrix
``load_visibility`` returns), ``camplace solve`` on the folder gives the same answer, and the
float32 run's optimum lies within the stated bound."""

from __future__ import annotations

import copy
import itertools
import json
from pathlib import Path

import numpy as np

import camplace
from camplace.cli import main
from camplace.instance import builtin_toml, parse_instance
from camplace.visibility.store import describe

ARGS = ["--candidates", "24", "--points", "400", "--k", "4", "--seed", "3", "--mode", "quality", "--no-cache"]


def _instance(tmp_path: Path, precision: str) -> Path:
    from camplace.instance.write import save_instance

    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["target"]["subdivisions"] = 2
    data["quality"] = {"mode": "graded", "max_incidence_deg": 80.0, "precision": precision}
    path = tmp_path / f"{precision}.toml"
    save_instance(parse_instance(data, "test", tmp_path), path)
    return path


def _enumerate(dense: np.ndarray, w: np.ndarray, k: int) -> tuple[float, tuple[int, ...]]:
    best = (-1.0, ())
    for c in itertools.combinations(range(dense.shape[1]), k):
        v = float(w @ dense[:, list(c)].max(axis=1))
        if v > best[0]:
            best = (v, c)
    return best


def test_graded_run_on_bytes(tmp_path: Path) -> None:
    out = tmp_path / "bytes"
    assert main(["run", str(_instance(tmp_path, "byte")), "-o", str(out), *ARGS]) == 0
    assert describe(out / "visibility.cpm")["structure"] == "colbytes"
    sol = json.loads((out / "solution.json").read_text())
    dense = camplace.load_visibility(out).toarray().astype(np.float64)  # float32 of q / 255
    assert np.all(np.abs(dense * 255 - np.round(dense * 255)) < 1e-4)  # multiples of 1/255
    w = np.loadtxt(out / "points.csv", delimiter=",", skiprows=1, usecols=-1)
    w = w / w.sum()  # the run's objective: points weigh 1 in total
    best, cams = _enumerate(dense, w, 4)
    chosen = tuple(sorted(c["candidate"] for c in sol["cameras"]))
    assert sol["status"] == "optimal"
    value = float(w @ dense[:, list(chosen)].max(axis=1))
    assert abs(value - sol["objective"]) <= 1e-6 and abs(value - best) <= 1e-6
    # camplace solve on the folder reads the bytes and answers the same
    assert main(["solve", str(out), "--mode", "quality", "--k", "4", "-o", str(tmp_path / "s.json")]) == 0
    again = json.loads((tmp_path / "s.json").read_text())
    assert tuple(sorted(again["selected"] if "selected" in again else [c["candidate"] for c in again["cameras"]])) == chosen
    assert again["objective"] == sol["objective"]
    # the float32 run: its optimum within sum(w) / 255 of the quantised one (each value within 1 / 255)
    out32 = tmp_path / "f32"
    assert main(["run", str(_instance(tmp_path, "float32")), "-o", str(out32), *ARGS]) == 0
    assert describe(out32 / "visibility.cpm")["structure"] != "colbytes"
    sol32 = json.loads((out32 / "solution.json").read_text())
    dense32 = camplace.load_visibility(out32).toarray().astype(np.float64)
    assert np.array_equal(dense32 > 0, dense > 0)
    best32, _ = _enumerate(dense32, w, 4)
    assert sol32["status"] == "optimal" and abs(sol32["objective"] - best32) <= 1e-6
    assert abs(best32 - best) <= float(w.sum()) / 255
