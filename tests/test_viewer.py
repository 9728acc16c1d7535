"""`reings view`: the splats' arrays against their definitions, and a real headless Chromium
screenshot of the served scene (skipped where no Chromium or viser is installed; CI installs
both)."""
from __future__ import annotations

import base64
import inspect
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

import reings
from reings.paths import look_at
from reings.viewer import SH_C0, splat_arrays


def test_splat_arrays_match_the_definitions():
    rng = np.random.default_rng(0)
    n = 50
    g = reings.Gaussians(means=rng.normal(size=(n, 3)), quats=rng.normal(size=(n, 4)),
                         log_scales=rng.uniform(-3, 0, (n, 3)), opacity_logits=rng.normal(size=n),
                         sh=rng.normal(size=(n, 4, 3)))
    c, cov, rgb, op = splat_arrays(g)
    for i in (0, 17, 49):
        q = g.quats[i].astype(np.float64)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        S = np.diag(np.exp(g.log_scales[i].astype(np.float64)))
        np.testing.assert_allclose(cov[i], R @ S @ S @ R.T, rtol=1e-5, atol=1e-8)
        np.testing.assert_allclose(np.linalg.eigvalsh(cov[i]), np.sort(np.diag(S @ S)), rtol=1e-4)
    np.testing.assert_allclose(rgb, np.clip(0.5 + SH_C0 * g.sh[:, 0], 0, 1), atol=1e-6)
    np.testing.assert_allclose(op[:, 0], 1 / (1 + np.exp(-g.opacity_logits)), rtol=1e-6)


def _block(colour, n=400, seed=0):
    """Opaque splats filling a block in front of the camera, all of one colour (degree-0 SH)."""
    rng = np.random.default_rng(seed)
    dc = (np.asarray(colour, np.float64) - 0.5) / SH_C0
    return reings.Gaussians(means=rng.uniform([-1, -0.7, 4], [1, 0.7, 5], (n, 3)), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                            log_scales=np.full((n, 3), np.log(0.12)), opacity_logits=np.full(n, 4.0),
                            sh=np.tile(dc, (n, 1, 1)))


class _Browser:
    """A headless Chromium driven over the DevTools protocol: the page is screenshotted again and
    again in real time until it shows what is expected or the deadline passes. (A one-shot
    `--screenshot` with a virtual-time budget captured the page before the splats had arrived over
    the websocket on a loaded 2-core CI machine, three browsers in a row.)

    The DevTools endpoint comes from `<user-data-dir>/DevToolsActivePort` (line 1 the port, line 2
    the browser's path), polled against a deadline, never from a blocking read of Chromium's output:
    that goes to a file (`<user-data-dir>.log`, quoted when the endpoint does not come). Chromium
    runs in its own session, and the whole process group (renderer, GPU and utility processes) is
    killed on close."""

    START_S = 60  # real seconds for Chromium to open its DevTools endpoint

    def __init__(self, tmp):
        from websockets.sync.client import connect

        assert _CHROME, "REINGS_REQUIRE_BROWSER is set but no Chromium is installed"
        tmp = Path(tmp)
        tmp.mkdir(parents=True, exist_ok=True)
        port_file = tmp / "DevToolsActivePort"
        port_file.unlink(missing_ok=True)
        self.log_path = tmp.with_name(tmp.name + ".log")
        self._log = open(self.log_path, "wb")
        try:
            self.proc = subprocess.Popen(
                [_CHROME, "--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", f"--user-data-dir={tmp}",
                 "--window-size=800,600", "--remote-debugging-port=0", "about:blank"],
                stdin=subprocess.DEVNULL, stdout=self._log, stderr=subprocess.STDOUT,
                start_new_session=True)  # its own process group: close() kills its children too
        except BaseException:
            self._log.close()
            raise
        self.ws = None
        try:
            url = self._endpoint(port_file, time.monotonic() + self.START_S)
            kw = {}
            if "proxy" in inspect.signature(connect).parameters:  # websockets >= 15 honours *_proxy
                kw["proxy"] = None  # variables by default; 127.0.0.1 is never behind a proxy
            self.ws = connect(url, max_size=2 ** 28, open_timeout=60, **kw)
        except BaseException:
            self._kill()
            raise
        self.n, self.session = 0, None

    def _endpoint(self, port_file, deadline):
        """ws://127.0.0.1:<port>/devtools/browser/<id> once DevToolsActivePort holds both lines and
        reads the same twice in a row (it is written in place); fails at the deadline or when
        Chromium exits first."""
        last = None
        while True:
            try:
                text = port_file.read_bytes().decode("ascii", errors="replace")
            except FileNotFoundError:
                text = None
            lines = text.splitlines() if text else []
            if len(lines) >= 2 and lines[0].strip().isdigit() and lines[1].strip().startswith("/devtools/"):
                if text == last:
                    return f"ws://127.0.0.1:{int(lines[0])}{lines[1].strip()}"
                last = text
            elif self.proc.poll() is not None:
                raise AssertionError(f"Chromium exited (status {self.proc.returncode}) before it opened "
                                     f"its DevTools endpoint; its output:\n{self._log_tail()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"Chromium did not open its DevTools endpoint within {self.START_S} s "
                                     f"({port_file}: {text!r}); its output:\n{self._log_tail()}")
            time.sleep(0.1)

    def _log_tail(self, n=4000):
        return self.log_path.read_bytes()[-n:].decode("utf-8", errors="replace")

    def _kill(self):
        """SIGKILL to Chromium's whole process group, then reap it (bounded wait)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass  # the group is gone already
        try:
            self.proc.wait(timeout=30)
        finally:
            self._log.close()

    def call(self, method, **params):
        self.n += 1
        msg = {"id": self.n, "method": method, "params": params}
        if self.session:
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        while True:
            r = json.loads(self.ws.recv(timeout=120))
            if r.get("id") == self.n:
                assert "error" not in r, f"{method}: {r['error']}"
                return r["result"]

    def open(self, url, width=800, height=600):
        target = self.call("Target.createTarget", url=url)["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1,
                  mobile=False)

    def screenshot(self):
        import cv2

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(int)

    def close(self):
        try:
            if self.ws is not None:
                self.ws.close()
        finally:
            self._kill()


_CHROME = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(not _CHROME and not os.environ.get("REINGS_REQUIRE_BROWSER"),
                    reason="no Chromium installed (CI installs it and sets REINGS_REQUIRE_BROWSER)")
@pytest.mark.parametrize("colour, channel", [((1.0, 0.05, 0.05), 0), ((0.05, 0.8, 0.05), 1)])
def test_the_browser_shows_the_scene(tmp_path, colour, channel):
    if not os.environ.get("REINGS_REQUIRE_BROWSER"):
        pytest.importorskip("viser")
    import cv2
    from reings.viewer import serve

    K = np.array([[300.0, 0, 200], [0, 300.0, 150], [0, 0, 1]])
    cam = look_at(np.zeros(3), np.array([0, 0, 4.5]), np.array([0, -1.0, 0]), K, 400, 300)
    server = serve(_block(colour), port=0, cameras=[cam])  # the OS picks a free port: no race between workers
    port = server.get_port()
    others = [c for c in range(3) if c != channel]
    browser = None
    try:
        browser = _Browser(tmp_path / "chrome")
        browser.open(f"http://127.0.0.1:{port}/")
        deadline = time.monotonic() + 150  # real seconds: the page, its websocket and the splats' sort
        while True:
            im = browser.screenshot()
            assert im.shape == (600, 800, 3), im.shape
            centre = im[200:400, 250:450]  # the middle of the 800x600 page: the block, seen from the camera
            hit = (centre[..., channel] > 150) & np.all(centre[..., others] < 90, axis=-1)
            if hit.mean() > 0.5 or time.monotonic() > deadline:
                break
            time.sleep(0.5)
    finally:
        if browser is not None:
            browser.close()
        server.stop()
    if hit.mean() <= 0.5:
        cv2.imwrite(str(tmp_path / "last.png"), im[..., ::-1].astype(np.uint8))
    assert hit.mean() > 0.5, (f"{hit.mean():.2f} of the centre shows the model's colour after 150 s "
                              f"(mean colour {im.reshape(-1, 3).mean(0).round(1)}; {tmp_path / 'last.png'})")
    anywhere = (im[..., others[0]] > 150) & (im[..., channel] < 90) & (im[..., others[1]] < 90)
    assert anywhere.mean() < 0.01  # and not the other model's colour
