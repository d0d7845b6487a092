"""A real browser for the tests: headless Chromium driven over the DevTools protocol (stdlib only).

Chromium's ``--remote-debugging-pipe`` reads NUL-terminated JSON commands on its fd 3 and writes
replies and events on its fd 4: no websocket library, no driver binary. The viewer renders
with SwiftShader, Chromium's software GPU (no GPU, no display needed).
"""

from __future__ import annotations

import base64
import colorsys
import io
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import pytest

#: Headless, no GPU: WebGL on SwiftShader (the Rerun viewer needs WebGL2 or WebGPU).
FLAGS = ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--window-size=1280,720", "--no-first-run", "--no-default-browser-check", "--disable-extensions",
         "--mute-audio")


def chromium_binary() -> str | None:
    """The Chromium (or Chrome) on this machine: ``$FXSWARM_CHROMIUM``, else the first on PATH."""
    named = os.environ.get("FXSWARM_CHROMIUM")
    if named:
        return named
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if shutil.which(name):
            return shutil.which(name)
    return None


def require_chromium() -> str:
    """The browser, or a skip; a failure where ``FXSWARM_REQUIRE_BROWSER=1`` (set by .ci/run
    where it installed Chromium): a browser test must not skip there."""
    from prerequisites import require

    require("browser")
    return chromium_binary()


class Browser:
    """One headless Chromium and one page of it; ``call`` sends a DevTools command to that page."""

    def __init__(self, binary: str, log: Path) -> None:
        self._profile = tempfile.mkdtemp(prefix="fxswarm-chromium-")
        to_chrome_r, self._to_chrome = os.pipe()
        self._from_chrome, from_chrome_w = os.pipe()

        def onto_3_and_4() -> None:  # in the child, before exec: the pipe ends Chromium expects
            os.dup2(to_chrome_r, 3)
            os.dup2(from_chrome_w, 4)

        self._log = log.open("w")
        self.proc = subprocess.Popen([binary, "--remote-debugging-pipe", f"--user-data-dir={self._profile}", *FLAGS,
                                      "about:blank"], stdin=subprocess.DEVNULL, stdout=self._log,
                                     stderr=subprocess.STDOUT, pass_fds=(3, 4), preexec_fn=onto_3_and_4)
        os.close(to_chrome_r)
        os.close(from_chrome_w)
        self._next = 0
        self._replies: dict[int, dict] = {}
        self.events: list[dict] = []
        self._cond = threading.Condition()
        self._reader = threading.Thread(target=self._read, name="devtools", daemon=True)
        self._reader.start()
        self.session = ""
        self._target = next(t for t in self.call("Target.getTargets")["targetInfos"] if t["type"] == "page")["targetId"]
        self._attach(self._target)

    def _attach(self, target: str) -> None:
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", page=True)

    def _read(self) -> None:
        buf = b""
        with os.fdopen(self._from_chrome, "rb", buffering=0) as pipe:
            while chunk := pipe.read(1 << 16):
                buf += chunk
                *messages, buf = buf.split(b"\0")
                with self._cond:
                    for raw in messages:
                        m = json.loads(raw)
                        if "id" in m:
                            self._replies[m["id"]] = m
                        else:
                            self.events.append(m)
                    self._cond.notify_all()

    def call(self, method: str, params: dict | None = None, page: bool = False, timeout: float = 60) -> dict:
        """Send a DevTools command (``page``: to the page's session) and wait for its result."""
        self._next += 1
        ident = self._next
        message = {"id": ident, "method": method, "params": params or {}}
        if page:
            message["sessionId"] = self.session
        os.write(self._to_chrome, json.dumps(message).encode() + b"\0")
        end = time.monotonic() + timeout
        with self._cond:
            while ident not in self._replies:
                left = end - time.monotonic()
                if left <= 0 or self.proc.poll() is not None:
                    raise TimeoutError(f"Chromium: no answer to {method} in {timeout:g} s "
                                       f"(exit status {self.proc.poll()})")
                self._cond.wait(min(left, 1.0))
            reply = self._replies.pop(ident)
        if "error" in reply:
            raise RuntimeError(f"Chromium: {method}: {reply['error']}")
        return reply["result"]

    def open(self, url: str) -> None:
        """Show ``url`` in a new tab (closing the last): the viewer's page does not survive a
        second navigation in the same tab (DevTools: "Not attached to an active page")."""
        old = self._target
        self._target = self.call("Target.createTarget", {"url": url})["targetId"]
        self._attach(self._target)
        self.call("Target.closeTarget", {"targetId": old})

    def screenshot(self) -> bytes:
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"}, page=True)["data"])

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True},
                         page=True)["result"].get("value")

    def console(self, limit: int = 20) -> list[str]:
        """The page's last errors and warnings (console, exceptions, failed loads), for a failure message."""
        out = []
        for e in list(self.events):
            p = e.get("params", {})
            if e.get("method") == "Log.entryAdded" and p["entry"]["level"] in ("error", "warning"):
                out.append(f"{p['entry']['level']}: {p['entry']['text']} {p['entry'].get('url', '')}")
            elif e.get("method") == "Runtime.exceptionThrown":
                out.append(f"exception: {p['exceptionDetails'].get('text')}")
            elif e.get("method") == "Runtime.consoleAPICalled" and p["type"] in ("error", "warning"):
                out.append(f"console.{p['type']}: " + " ".join(str(a.get("value", a.get("description", "")))[:300]
                                                           for a in p["args"]))
        return out[-limit:]

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout=5)
        except (OSError, TimeoutError, RuntimeError):
            pass
        try:
            self.proc.wait(15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(15)
        os.close(self._to_chrome)
        self._log.close()
        shutil.rmtree(self._profile, ignore_errors=True)


def colour_pixels(png: bytes, rgb: int, box: tuple[float, float, float, float], hue_tol: float = 0.025,
                  min_saturation: float = 0.3, min_value: float = 0.25) -> int:
    """Pixels in ``box`` (fractions of width and height: left, top, right, bottom) whose hue is
    within ``hue_tol`` (fraction of the circle) of ``rgb``'s, saturated and bright enough: a
    shaded sphere of that colour keeps its hue, the grey background and white lines have none."""
    import numpy as np
    from PIL import Image

    img = Image.open(io.BytesIO(png)).convert("HSV")
    w, h = img.size
    hsv = np.asarray(img.crop((int(box[0] * w), int(box[1] * h), int(box[2] * w), int(box[3] * h))),
                     dtype=float) / 255
    target = colorsys.rgb_to_hsv(((rgb >> 16) & 255) / 255, ((rgb >> 8) & 255) / 255, (rgb & 255) / 255)[0]
    d = np.abs(hsv[..., 0] - target)
    near = np.minimum(d, 1 - d) <= hue_tol
    return int(np.count_nonzero(near & (hsv[..., 1] >= min_saturation) & (hsv[..., 2] >= min_value)))
