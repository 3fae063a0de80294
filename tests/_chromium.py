"""A headless Chromium driven through the DevTools protocol, for the HTML pages camplace writes.

Chromium is driven over ``--remote-debugging-pipe`` (file descriptors 3 and 4, NUL-separated JSON),
so no port is opened and no third-party package is needed; its network is cut off (host resolver
mapped to nothing, a dead proxy) and every request a page makes is recorded. WebGL (the 3D view)
runs on SwiftShader, Chromium's CPU renderer.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-quic", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--disable-extensions", "--disable-default-apps",
    "--use-angle=swiftshader", "--use-gl=angle", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>",
    "--remote-debugging-pipe",
]


def chromium_path() -> str:
    """The Chromium executable, or fail saying how to install it (the CI installs it; never skip)."""
    for cand in (os.environ.get("CAMPLACE_CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if cand and shutil.which(cand):
            return shutil.which(cand)
    pytest.fail("Chromium is needed to check the HTML pages in a real browser: install it with "
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

    def evaluate(self, expression: str, session: str, timeout: float = 60):
        """The JSON value of a JavaScript expression (awaited when it is a promise)."""
        res = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True}, session=session,
                        timeout=timeout)
        if "exceptionDetails" in res:
            raise RuntimeError(f"{expression[:80]}: {res['exceptionDetails'].get('text')}")
        return res["result"].get("value")

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


# Once the page has loaded: wait for the 3D plot (data-ready set by camplace.plotly3d) and two frames
# more, then describe it: its WebGL canvases, the data tag, the traces plotly drew and the element's box.
SCENE_PROBE = """
(async () => {
  const id = %(id)s;
  const end = Date.now() + %(timeout_ms)d;
  let gd = document.getElementById(id);
  while (!(gd && gd.dataset.ready === '1') && Date.now() < end) {
    await new Promise(r => setTimeout(r, 100));
    gd = document.getElementById(id);
  }
  if (!gd) return {found: false};
  gd.scrollIntoView();
  for (let i = 0; i < 3; i++) await new Promise(r => requestAnimationFrame(() => setTimeout(r, 50)));
  const canvases = Array.from(gd.querySelectorAll('canvas')).map(c => ({
    w: c.width, h: c.height,
    webgl: !!(c.getContext('webgl2') || c.getContext('webgl') || c.getContext('experimental-webgl'))}));
  const tag = document.getElementById(id + '-data');
  const r = gd.getBoundingClientRect();
  const lg = gd.querySelector('.legend');
  const l = lg ? lg.getBoundingClientRect() : null;
  return {found: true, tag: gd.tagName,
          legend: l ? {x: l.left - r.left, y: l.top - r.top, width: l.width, height: l.height} : null, ready: gd.dataset.ready === '1', canvases: canvases,
          data: tag ? JSON.parse(tag.textContent) : null,
          traces: (gd._fullData || []).map(t => ({type: t.type, name: t.name, mode: t.mode || null, group: t.legendgroup || null,
                                                   visible: t.visible, n: t.x ? t.x.length : 0, faces: t.i ? t.i.length : 0})),
          box: {x: r.left + window.scrollX, y: r.top + window.scrollY, width: r.width, height: r.height}};
})()
"""


def open_in_chromium(page: Path, screenshot: Path, width: int = 1200, scene_id: str | None = None,
                     scene_screenshot: Path | None = None) -> dict:
    """Load ``page``; return its images, console errors and requests; save a full-page screenshot.

    With ``scene_id``, also wait for that 3D plot, describe it (``"scene"``: see SCENE_PROBE) and
    save a screenshot of its element to ``scene_screenshot``.
    """
    profile = tempfile.mkdtemp(prefix="camplace-chromium-")
    dt = DevTools(chromium_path(), profile)
    try:
        tid = dt.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        sid = dt.send("Target.attachToTarget", {"targetId": tid, "flatten": True})["sessionId"]
        for m in ("Runtime.enable", "Log.enable", "Page.enable", "Network.enable"):
            dt.send(m, session=sid)
        dt.send("Emulation.setDeviceMetricsOverride", {"width": width, "height": 900, "deviceScaleFactor": 1, "mobile": False}, session=sid)
        dt.send("Page.navigate", {"url": page.resolve().as_uri()}, session=sid)
        dt.wait_event("Page.loadEventFired", timeout=120)
        scene = None
        if scene_id is not None:
            scene = dt.evaluate(SCENE_PROBE % {"id": json.dumps(scene_id), "timeout_ms": 90_000}, sid, timeout=120)
            if scene.get("found") and scene_screenshot is not None:
                b = scene["box"]
                shot = dt.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True,
                                                          "clip": {**b, "scale": 1}}, session=sid, timeout=120)
                scene_screenshot.write_bytes(base64.b64decode(shot["data"]))
        info = dt.evaluate("({title: document.title, images: Array.from(document.images).map("
                           "i => ({alt: i.alt, complete: i.complete, w: i.naturalWidth, h: i.naturalHeight}))})", sid)
        dt.evaluate("window.scrollTo(0, 0)", sid)
        height = dt.send("Page.getLayoutMetrics", session=sid)["cssContentSize"]["height"]
        shot = dt.send("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True,
                                                  "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1}}, session=sid,
                       timeout=120)
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
        return {"title": info["title"], "images": info["images"], "errors": errors, "requests": requests, "height": height,
                "scene": scene}
    finally:
        dt.close()
        shutil.rmtree(profile, ignore_errors=True)


def external_requests(page: Path, requests: list[str]) -> list[str]:
    """The requests other than the page itself and ``data:`` URIs."""
    page_url = page.resolve().as_uri()
    return [u for u in requests if not (u == page_url or u.startswith("data:"))]


def png_colours(png: bytes) -> tuple[tuple[int, int], "object"]:
    """(width, height) of a PNG and its pixels as an (h, w, 3) uint8 RGB array."""
    import cv2
    import numpy as np

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "not a PNG OpenCV can read"
    return (img.shape[1], img.shape[0]), img[:, :, ::-1]


def without_legend(rgb, scene: dict):
    """The scene screenshot with the legend's box painted white (its swatches share the colours of the plot)."""
    out = rgb.copy()
    box = scene.get("legend")
    if box:
        x0, y0 = max(0, int(box["x"]) - 2), max(0, int(box["y"]) - 2)
        out[y0:int(box["y"] + box["height"]) + 2, x0:int(box["x"] + box["width"]) + 2] = 255
    return out


def distinct_colours(rgb) -> int:
    """Number of distinct RGB colours of an (h, w, 3) uint8 image."""
    import numpy as np

    flat = rgb.reshape(-1, 3).astype(np.int64)
    return int(len(np.unique((flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2])))


def pixels_near(rgb, colour_hex: str, tol: int = 24) -> int:
    """Pixels within ``tol`` (max abs difference per channel) of ``#rrggbb``."""
    import numpy as np

    c = np.array([int(colour_hex[i:i + 2], 16) for i in (1, 3, 5)])
    return int(np.count_nonzero(np.all(np.abs(rgb.astype(np.int64) - c) <= tol, axis=-1)))
