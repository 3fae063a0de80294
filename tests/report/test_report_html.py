"""report.html end to end, checked in a real headless Chromium through the DevTools protocol
(:mod:`tests._chromium`): its network is cut off and every request the page makes is recorded and
must be the page itself or a ``data:`` URI; the 3D view must draw (WebGL on SwiftShader).
"""

from __future__ import annotations

import copy
import inspect
import json
import os
import re
import shutil
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np

import camplace
import pytest
import scipy.sparse as sp

import camplace.cli
from camplace.instance import builtin_toml, parse_instance
from camplace.pipeline import run
from camplace.report.build import BUNDLE_SAMPLERS, BUNDLE_SYSTEMS, run_report_bundle, write_report
from camplace.report.campaign import Campaign
from camplace.report.run_scene import PLOT_ID, SECTION_ID
from camplace.validation import render_run, validate_runs
from tests._chromium import distinct_colours, external_requests, open_in_chromium, pixels_near, png_colours, without_legend

NAME = "comet<&>\"q'"  # an instance name that must be escaped everywhere
SCRIPT = re.compile(r"<script[^>]*>.*?</script>", re.S)


def small_instance():
    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["name"] = NAME
    data["camera"].update(width_px=320, height_px=240)
    data["target"]["subdivisions"] = 2
    data["frames"] = [{"weight": 1.0, "position_m": [12.0 + 0.3 * i, 1.5, 1.5]} for i in range(2)]
    return parse_instance(data, "test", Path.cwd())


@pytest.fixture(scope="module")
def outdir(tmp_path_factory) -> Path:
    """A run with campaigns (run_report_bundle), renders, a validation and light curves."""
    out = tmp_path_factory.mktemp("report") / "run"
    run(small_instance(), seed=3, candidates=120, points=1200, outdir=out)
    first = run_report_bundle(out, systems=40)
    assert first == out / "report.html" and first.is_file()
    render_run(out)
    validate_runs([out], out / "validation", random_systems=1)
    rows = ["camera,frame,observed_weight"] + [f"camera_{c},{f},{0.1 * c + 0.05 * f}" for c in (1, 2, 3) for f in (0, 1)]
    (out / "render" / "light_curves.csv").write_text("\n".join(rows) + "\n")
    # a campaign folder whose name needs escaping
    shutil.copytree(out / "campaign-uniform", out / "campaign-<b>&'x'")
    write_report(out)
    return out


def test_bundle_defaults() -> None:
    sig = inspect.signature(run_report_bundle)
    assert sig.parameters["systems"].default == BUNDLE_SYSTEMS == 200
    assert tuple(sig.parameters["campaign_samplers"].default) == BUNDLE_SAMPLERS == ("uniform", "chaotic")


def test_bundle_wrote_two_campaigns_on_the_run_rows(outdir) -> None:
    sol = json.loads((outdir / "solution.json").read_text())
    for s in ("uniform", "chaotic"):
        c = Campaign.load(outdir / f"campaign-{s}")
        assert c.n_systems == 40 and c.sampler == s and c.seed == sol["seed"] and c.n_points == sol["n_points"] and c.k == 3
    assert (outdir / "samplers.json").is_file()


def test_report_content(outdir) -> None:
    text = (outdir / "report.html").read_text()
    # every user string escaped
    assert NAME not in text and "comet&lt;&amp;&gt;&quot;q&#x27;" in text
    assert "campaign-<b>" not in text and "campaign-&lt;b&gt;&amp;&#x27;x&#x27;" in text
    # the only scripts are the 3D view's: its data tag, plotly.js and the plot; no URL outside plotly.js
    scripts = SCRIPT.findall(text)
    assert len(scripts) == 3
    assert scripts[0].startswith("<script type='application/json' id='scene3d-data'>")
    assert "Plotly" in scripts[1] and len(scripts[1]) > 1_000_000
    assert "Plotly.newPlot" in scripts[2]
    rest = SCRIPT.sub("", text)
    assert "<script" not in rest.lower()
    for part in (rest, scripts[0], scripts[2]):
        assert "http://" not in part and "https://" not in part
    alts = re.findall(r'<img src="data:image/png;base64,[A-Za-z0-9+/=]+" alt="([^"]*)"', text)
    assert len(alts) == text.count("<img ")
    for c in ("campaign-chaotic", "campaign-uniform", "campaign-&lt;b&gt;&amp;&#x27;x&#x27;"):
        assert f"objective histogram of {c}" in alts
    for needed in ("best objective and discrepancy per sampler", "vision-cone density heatmaps", "legacy score against objective", "light curves"):
        assert needed in alts
    renders = [a for a in alts if a.startswith("render ")]
    assert len(renders) == 6  # 3 cameras x 2 frames
    overlays = [a for a in alts if a.startswith("overlay.")]
    assert len(overlays) == 3  # system 1 only
    assert "heatmap_coverage.png" in alts and "kde_scores.png" in alts
    sol = json.loads((outdir / "solution.json").read_text())
    assert f"{sol['objective']:.6f}" in text and f"{sol['bound']:.6f}" in text
    assert "on the same matrix: <b>holds</b>" in text
    assert "Spearman rho" in text and "optimised percentile" in text
    assert "light_curves.csv" in text


class ElementIds(HTMLParser):
    """Every ``id`` of a page as (id, tag, the tags open around it, outermost first)."""

    VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "wbr"}

    def __init__(self) -> None:
        super().__init__()
        self.open: list[str] = []
        self.ids: list[tuple[str, str, tuple[str, ...]]] = []
        self.hrefs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list) -> None:
        a = dict(attrs)
        if "id" in a:
            self.ids.append((a["id"], tag, tuple(self.open)))
        if tag == "a" and (a.get("href") or "").startswith("#"):
            self.hrefs.append(a["href"][1:])
        if tag not in self.VOID:
            self.open.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if tag in self.open:
            while self.open.pop() != tag:
                pass


def test_report_ids_are_unique_and_the_plot_lands_in_its_div(outdir) -> None:
    """Issue 33: the heading and the plot shared ``scene3d``, so plotly drew into the heading."""
    text = (outdir / "report.html").read_text()
    page = ElementIds()
    page.feed(text)
    ids = [i for i, _, _ in page.ids]
    assert len(ids) >= 10 and sorted({i for i in ids if ids.count(i) > 1}) == []
    where = {i: (tag, around) for i, tag, around in page.ids}
    assert where[SECTION_ID][0] == "h2"
    tag, around = where[PLOT_ID]
    assert tag == "div" and "h2" not in around and around[-1] == "div"  # inside the view's bordered box
    assert where[f"{PLOT_ID}-data"][0] == "script"
    # plotly draws into the plot's div, and every navigation link has its target
    assert re.findall(r"Plotly\.newPlot\(\s*[\"']([^\"']+)[\"']", text) == [PLOT_ID]
    assert SECTION_ID in page.hrefs and set(page.hrefs) <= set(ids)


def test_report_says_what_require_light_is(outdir) -> None:
    """The instance table shows require_light and what it means (an unlit half is not bad placement)."""
    text = (outdir / "report.html").read_text()
    assert "lit points only (require_light)" in text
    assert "false: lit and unlit points count alike" in text


def scene_data(page: Path) -> dict:
    m = re.search(r"<script type='application/json' id='scene3d-data'>(.*?)</script>", page.read_text(), re.S)
    assert m is not None
    return json.loads(m.group(1))


def test_scene3d_coverage_matches_the_matrix(outdir) -> None:
    """Oracle: the coverage of each peak-frame row recounted from visibility.cpm, points.csv and solution.json."""
    d = scene_data(outdir / "report.html")
    sol = json.loads((outdir / "solution.json").read_text())
    assert d["system"] == "the run's system"  # no campaign system beat it (the report says the guarantee holds)
    sel = [int(c["candidate"]) for c in sol["cameras"]]
    M = camplace.load_visibility(outdir).tocsc()
    frame = np.loadtxt(outdir / "points.csv", delimiter=",", skiprows=1)[:, 7].astype(int)
    peak = sol["peak_frame"]
    rows = np.flatnonzero(frame == peak)
    counts = np.asarray((M[:, sel] > 0).sum(axis=1)).ravel()[rows]
    assert d["n_cameras"] == len(d["cameras"]) == len(sel) == 3
    for cam, rec in zip(d["cameras"], sol["cameras"], strict=True):
        assert cam["position"] == pytest.approx(rec["position"], abs=1e-5)
        assert cam["forward"] == pytest.approx(np.array(rec["rotation"])[:, 2], abs=1e-5)
        assert rec["near_m"] < cam["depth_m"] <= rec["far_m"]
    cov = d["coverage"]
    assert cov["n_points"] == len(rows) > 0
    assert cov["points"] == [int(np.sum(np.minimum(counts, 3) == c)) for c in range(4)]
    assert cov["count"] == counts[cov["index"]].tolist()
    assert d["frame"] == peak and d["n_frames"] == 2
    centres = np.array(d["trajectory"]["centres"])
    assert centres.shape == (2, 3) and centres[1] - centres[0] == pytest.approx([0.3, 0.0, 0.0], abs=1e-4)
    # the best and the median system of each campaign (three campaign folders), muted
    assert len(d["other_systems"]) == 6 and all(s["n_cameras"] == 3 for s in d["other_systems"])
    assert sorted({s["name"].split(" ")[-3] for s in d["other_systems"]}) == ["best", "median"]


def check_scene_in_chromium(res: dict, page: Path, shot: Path, n_cameras: int) -> None:
    """The 3D view drew with WebGL, with ``n_cameras`` frusta and every drawn point, and its screenshot is not blank."""
    sc = res["scene"]
    assert sc["found"] and sc["ready"], sc
    assert sc["tag"] == "DIV"  # the plot's own element (a heading sharing its id received the plot: issue 33)
    assert any(c["webgl"] and c["w"] > 100 and c["h"] > 100 for c in sc["canvases"])
    d = sc["data"]  # read back from the page by the browser
    assert d == scene_data(page) and d["n_cameras"] == n_cameras
    frusta = [t for t in sc["traces"] if t["mode"] == "lines" and (t["group"] or "").startswith("camera")]
    assert len(frusta) == n_cameras and all(t["visible"] is True for t in frusta)
    drawn = [t for t in sc["traces"] if (t["name"] or "").startswith("seen by")]
    assert len(drawn) == 4 and sum(t["n"] for t in drawn) == d["coverage"]["n_drawn"]
    (w, h), rgb = png_colours(shot.read_bytes())
    assert (w, h) == (round(sc["box"]["width"]), round(sc["box"]["height"]))
    assert distinct_colours(rgb) > 300
    # the coverage colours are drawn in the 3D canvas (legend masked): the most frequent class at least
    top = int(np.argmax(d["coverage"]["points"]))
    assert sc["legend"] is not None and pixels_near(without_legend(rgb, sc), d["coverage"]["colours"][top]) > 20


def test_report_opens_in_chromium_without_errors(outdir, tmp_path) -> None:
    shot, scene_shot = tmp_path / "report.png", tmp_path / "scene3d.png"
    res = open_in_chromium(outdir / "report.html", shot, scene_id="scene3d", scene_screenshot=scene_shot)
    assert res["errors"] == []
    assert res["title"] == f"camplace report: {NAME}"
    n_img = (outdir / "report.html").read_text().count("<img ")
    assert len(res["images"]) == n_img >= 12
    bad = [i for i in res["images"] if not (i["complete"] and i["w"] > 0 and i["h"] > 0)]
    assert bad == []
    assert external_requests(outdir / "report.html", res["requests"]) == []
    check_scene_in_chromium(res, outdir / "report.html", scene_shot, 3)
    png = shot.read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000
    w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert w == 1200 and h == pytest.approx(res["height"], abs=2) and h > 2000
    keep = os.environ.get("CAMPLACE_REPORT_SCREENSHOT")
    if keep:
        shutil.copy(shot, keep)
        shutil.copy(scene_shot, Path(keep).with_suffix(".scene3d.png"))


def test_report_verb_and_its_errors(outdir, tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(camplace.cli, "VERB_MODULES", ("camplace.validation.cli", "camplace.report.cli"))
    out = tmp_path / "r.html"
    assert camplace.cli.main(["report", str(outdir), "--no-sampler-study", "-o", str(out)]) == 0
    assert out.is_file() and "Sampler study skipped" in out.read_text()
    capsys.readouterr()
    assert camplace.cli.main(["report", str(tmp_path / "nothing")]) == 2
    assert "solution.json" in capsys.readouterr().err
    assert camplace.cli.main(["report", str(outdir), "--ladder", "1,x"]) == 2
    assert "--ladder" in capsys.readouterr().err
    # without matplotlib: one line naming the extra
    for mod in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, mod, None)
    assert camplace.cli.main(["report", str(outdir), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: the report needs the optional report extra: pip install 'camplace[report]'"


def test_matrix_light_curves_without_csv(tmp_path) -> None:
    """A multi-frame run without light_curves.csv gets per-frame observed weights from its matrix."""
    out = tmp_path / "run"
    run(small_instance(), seed=4, candidates=30, points=300, outdir=out)
    (out / "light_curves.csv").unlink(missing_ok=True)
    text = write_report(out, sampler_study=False).read_text()
    assert 'alt="light curves"' in text and "from the visibility matrix" in text
    assert "Validation has not run" in text


def test_validate_runs_writes_the_3d_view(outdir) -> None:
    """validate on a run folder draws its system (strong) and the random system (muted) around the target."""
    d = scene_data(outdir / "validation" / "scene3d.html")
    sol = json.loads((outdir / "solution.json").read_text())
    assert d["kind"] == "validation" and d["mode"] == "runs" and d["frame"] == 0
    assert d["n_cameras"] == 3
    for cam, rec in zip(d["cameras"], sol["cameras"], strict=True):
        assert cam["position"] == pytest.approx(rec["position"], abs=1e-5)
    assert [(s["name"], s["n_cameras"]) for s in d["other_systems"]] == [("system 2", 3)]
    assert d["occluders"][0]["name"] == "corridor" and d["coverage"]["n_points"] == 4000
