"""report.html end to end, checked in a real headless Chromium through the DevTools protocol.

Chromium is driven over ``--remote-debugging-pipe`` (file descriptors 3 and 4, NUL-separated JSON),
so no port is opened and no third-party package is needed; its network is cut off (host resolver
mapped to nothing, a dead proxy) and every request the page makes is recorded and must be the page
itself or a ``data:`` URI.
"""

from __future__ import annotations

import base64
import copy
import fcntl
import inspect
import json
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

import camplace.cli
from camplace.instance import builtin_toml, parse_instance
from camplace.pipeline import run
from camplace.report.build import BUNDLE_SAMPLERS, BUNDLE_SYSTEMS, run_report_bundle, write_report
from camplace.report.campaign import Campaign
from camplace.validation import render_run, validate_runs

NAME = "comet<&>\"q'"  # an instance name that must be escaped everywhere
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--disable-extensions", "--disable-default-apps",
    "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>",
    "--remote-debugging-pipe",
]


def chromium_path() -> str:
    """The Chromium executable, or fail saying how to install it (the CI installs it; never skip)."""
    for cand in (os.environ.get("CAMPLACE_CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if cand and shutil.which(cand):
            return shutil.which(cand)
    pytest.fail("Chromium is needed to check report.html in a real browser: install it with "
                "'sudo apt-get install -y chromium' (Debian/Ubuntu) or set CAMPLACE_CHROMIUM=/path/to/chrome")


class DevTools:
    """A headless Chromium driven over the DevTools pipe."""

    def __init__(self, exe: str, profile: str) -> None:
        to_r, self.to_w = os.pipe()
        self.from_r, from_w = os.pipe()
        # move the child's ends above 10 so that placing them on 3 and 4 cannot clobber one another
        hi_r, hi_w = fcntl.fcntl(to_r, fcntl.F_DUPFD, 10), fcntl.fcntl(from_w, fcntl.F_DUPFD, 10)
        os.close(to_r)
        os.close(from_w)

        def child() -> None:  # Chromium reads commands on fd 3 and answers on fd 4
            os.dup2(hi_r, 3)
            os.dup2(hi_w, 4)

        try:
            self.proc = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "about:blank"],
                                         preexec_fn=child, pass_fds=(3, 4), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        finally:
            os.close(hi_r)
            os.close(hi_w)
        self.buf = b""
        self.next_id = 0
        self.events: list[dict] = []

    def _read(self, timeout: float) -> dict:
        end = time.monotonic() + timeout
        while b"\0" not in self.buf:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError("Chromium did not answer in time")
            ready, _, _ = select.select([self.from_r], [], [], left)
            if ready:
                chunk = os.read(self.from_r, 1 << 20)
                if not chunk:
                    raise RuntimeError("Chromium closed the DevTools pipe: " + self.proc.stderr.read().decode(errors="replace")[-2000:])
                self.buf += chunk
        msg, self.buf = self.buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 60) -> dict:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.to_w, json.dumps(msg).encode() + b"\0")
        while True:
            m = self._read(timeout)
            if m.get("id") == self.next_id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def wait_event(self, method: str, timeout: float = 60) -> dict:
        for i, e in enumerate(self.events):
            if e.get("method") == method:
                return self.events.pop(i)
        end = time.monotonic() + timeout
        while True:
            m = self._read(max(0.01, end - time.monotonic()))
            if m.get("method") == method:
                return m
            self.events.append(m)

    def close(self) -> None:
        try:
            self.send("Browser.close", timeout=10)
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self.to_w)
        os.close(self.from_r)


def open_in_chromium(page: Path, screenshot: Path, width: int = 1200) -> dict:
    """Load ``page``; return its images, console errors and requests; save a full-page screenshot."""
    profile = tempfile.mkdtemp(prefix="camplace-chromium-")
    dt = DevTools(chromium_path(), profile)
    try:
        tid = dt.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        sid = dt.send("Target.attachToTarget", {"targetId": tid, "flatten": True})["sessionId"]
        for m in ("Runtime.enable", "Log.enable", "Page.enable", "Network.enable"):
            dt.send(m, session=sid)
        dt.send("Emulation.setDeviceMetricsOverride", {"width": width, "height": 900, "deviceScaleFactor": 1, "mobile": False}, session=sid)
        dt.send("Page.navigate", {"url": page.resolve().as_uri()}, session=sid)
        dt.wait_event("Page.loadEventFired")
        expr = ("JSON.stringify({title: document.title, images: Array.from(document.images).map("
                "i => ({alt: i.alt, complete: i.complete, w: i.naturalWidth, h: i.naturalHeight}))})")
        info = json.loads(dt.send("Runtime.evaluate", {"expression": expr, "returnByValue": True}, session=sid)["result"]["value"])
        height = dt.send("Page.getLayoutMetrics", session=sid)["cssContentSize"]["height"]
        shot = dt.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True,
                                                  "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1}}, session=sid)
        screenshot.write_bytes(base64.b64decode(shot["data"]))
        dt.send("Runtime.evaluate", {"expression": "1"}, session=sid)  # flush pending events
        errors, requests = [], []
        for e in dt.events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Runtime.exceptionThrown":
                errors.append(p["exceptionDetails"].get("text", "exception"))
            elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                errors.append(json.dumps(p.get("args"))[:300])
            elif m == "Log.entryAdded" and p["entry"].get("level") == "error":
                errors.append(p["entry"].get("text", "error"))
            elif m == "Network.requestWillBeSent":
                requests.append(p["request"]["url"])
        return {"title": info["title"], "images": info["images"], "errors": errors, "requests": requests, "height": height}
    finally:
        dt.close()
        shutil.rmtree(profile, ignore_errors=True)


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
    assert "<script" not in text.lower() and "http://" not in text and "https://" not in text
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


def test_report_opens_in_chromium_without_errors(outdir, tmp_path) -> None:
    shot = tmp_path / "report.png"
    res = open_in_chromium(outdir / "report.html", shot)
    assert res["errors"] == []
    assert res["title"] == f"camplace report: {NAME}"
    n_img = (outdir / "report.html").read_text().count("<img ")
    assert len(res["images"]) == n_img >= 12
    bad = [i for i in res["images"] if not (i["complete"] and i["w"] > 0 and i["h"] > 0)]
    assert bad == []
    page_url = (outdir / "report.html").resolve().as_uri()
    external = [u for u in res["requests"] if not (u == page_url or u.startswith("data:"))]
    assert external == []
    png = shot.read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000
    w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert w == 1200 and h == pytest.approx(res["height"], abs=2) and h > 2000
    keep = os.environ.get("CAMPLACE_REPORT_SCREENSHOT")
    if keep:
        shutil.copy(shot, keep)


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
