"""The report of a ``--mode setcover`` run says how many cameras cover it all and how far that is proven.

Oracle: the run folder's matrix (``visibility.cpm``) and ``points.csv``, read with numpy: the
cameras named in the report cover every point of positive weight some candidate sees, and the
lower bound in the report is the one in ``solution.json``.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from camplace.pipeline import run
from camplace.report.build import run_report_bundle
from camplace.visibility.store import load_visibility
from tests.report.test_report_html import small_instance


@pytest.mark.slow
def test_setcover_report_says_how_many_cameras_cover_it_all(tmp_path) -> None:
    out = tmp_path / "run"
    run(small_instance(), seed=1, candidates=60, points=600, outdir=out, mode="setcover", time_limit_s=20)
    run_report_bundle(out, systems=3)
    sol = json.loads((out / "solution.json").read_text())
    html = (out / "report.html").read_text()

    q = load_visibility(out).tocsc()
    head = (out / "points.csv").read_text().splitlines()[0].split(",")
    w = np.loadtxt(out / "points.csv", delimiter=",", skiprows=1, ndmin=2)[:, head.index("weight")]
    seen_by_any = np.diff(q.tocsr().indptr) > 0
    sel = [c["candidate"] for c in sol["cameras"]]
    seen = np.asarray((q[:, sel] > 0).sum(axis=1)).ravel() > 0
    assert np.all(seen[(w > 0) & seen_by_any])

    m = re.search(r"cameras that cover it all</th><td class='l'>(\d+) new camera\(s\) cover every point a candidate sees",
                  html)
    assert m is not None
    assert int(m.group(1)) == len(sel) == sol["objective"]
    assert "bound" in sol and sol["bound"] <= sol["objective"]
    lb = re.search(r"lower bound on the number of cameras</th><td class='l'>([0-9.]+)", html)
    assert lb is not None and float(lb.group(1)) == sol["bound"]
    if sol["status"] == "optimal":
        assert "no fewer cameras can do it (optimal)" in html
