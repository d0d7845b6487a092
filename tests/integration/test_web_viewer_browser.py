"""The live web viewer of a running swarm, in a real browser: the robots are drawn.

``fxswarm run paper-fast --clock realtime --rerun web``: real processes over Zenoh, the logger
serving the Rerun web viewer on free ports. Headless Chromium (tests/browser_support.py, WebGL on
SwiftShader) opens the viewer page the logger printed and takes screenshots until the swarm view
shows the robots in their colours (logger/style.py's palette); the same check on the viewer
with no data (its welcome screen, the page fully loaded) must find none, so it is not passed by
the viewer's own chrome. Where no Chromium is installed the test skips, unless
``FXSWARM_REQUIRE_BROWSER=1`` (.ci/run sets it where apt-get can install one): then it fails.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote

import pytest

from browser_support import Browser, colour_pixels, require_chromium
from fxswarm.logger import style
from fxswarm.testing import scenario_with

pytestmark = [pytest.mark.zenoh, pytest.mark.browser, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parents[2]
ROBOTS = 6
#: The swarm's 3D view: the left three fifths of the viewer, below its top bar, above the time panel.
SWARM_VIEW = (0.0, 0.09, 0.58, 0.9)
#: The top bar's left end, where the viewer draws its (white) logo once the app runs.
LOGO = (0.0, 0.0, 0.08, 0.06)
MIN_PIXELS = 40  # of one robot's colour: a sphere a few pixels across is drawn with more
MIN_ROBOTS = 4  # colours found of the six: one or two may hide behind another or an obstacle


def robots_seen(png: bytes) -> dict[str, int]:
    """Robot colour (hex) -> pixels of that colour in the swarm view."""
    return {style.robot_hex(i): colour_pixels(png, style.robot_rgb(i), SWARM_VIEW) for i in range(ROBOTS)}


def drawn(seen: dict[str, int]) -> bool:
    return sum(n >= MIN_PIXELS for n in seen.values()) >= MIN_ROBOTS


def wait_for_url(log: Path, proc: subprocess.Popen, timeout: float) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            pytest.fail(f"fxswarm run ended ({proc.returncode}) before its logger served the web viewer")
        text = log.read_text() if log.exists() else ""
        m = re.search(r"web viewer at (http://\S+)", text)
        if m:
            return m.group(1)
        time.sleep(0.2)
    pytest.fail(f"no 'web viewer at' line in {log} after {timeout:g} s")


def test_the_web_viewer_draws_the_robots_of_a_running_swarm(tmp_path):
    binary = require_chromium()
    # Long enough that the swarm still flies while the browser starts and loads the viewer;
    # the test stops the run once it has seen the robots.
    config = scenario_with(ROOT / "configs" / "paper-fast.toml", tmp_path, duration=300.0)
    out = tmp_path / "run"
    run = subprocess.Popen([sys.executable, "-m", "fxswarm.cli", "run", str(config), "--clock", "realtime",
                            "--rerun", "web", "--out", str(out), "--quiet"], cwd=ROOT, stdout=subprocess.DEVNULL,
                           stderr=(tmp_path / "run.log").open("w"))
    browser = None
    try:
        url = wait_for_url(out / "logs" / "logger.log", run, 180)
        page, _, source = url.partition("/?url=")
        browser = Browser(binary, tmp_path / "chromium.log")
        # The viewer with no data: its welcome screen, once the app started (index.html sets
        # window._handle then) and drew its top bar (the white rerun logo).
        browser.open(page + "/")
        end = time.monotonic() + 180
        while True:
            empty = browser.screenshot() if browser.evaluate("window._handle !== undefined") else b""
            if empty and colour_pixels(empty, 0xFFFFFF, LOGO, hue_tol=1.0, min_saturation=0.0, min_value=0.9) > 50:
                break
            if time.monotonic() > end:
                pytest.fail(f"the viewer app did not start in 180 s: {browser.console()}")
            time.sleep(0.5)
        (tmp_path / "empty.png").write_bytes(empty)
        assert not drawn(robots_seen(empty)), f"robot colours without any data: {robots_seen(empty)}"
        # The swarm's live data.
        browser.open(f"{page}/?url={quote(source, safe='')}")
        end = time.monotonic() + 180
        seen: dict[str, int] = {}
        while True:
            shot = browser.screenshot()
            seen = robots_seen(shot)
            if drawn(seen):
                break
            if time.monotonic() > end or run.poll() is not None:
                (tmp_path / "last.png").write_bytes(shot)
                pytest.fail(f"no robots drawn in 180 s (pixels per robot colour {seen}; screenshot "
                            f"{tmp_path / 'last.png'}; run {'ended' if run.poll() is not None else 'flying'}); "
                            f"page said: {browser.console()}")
            time.sleep(2)
        (tmp_path / "robots.png").write_bytes(shot)
        print(f"robots drawn: pixels per colour {seen} ({tmp_path / 'robots.png'})")
    finally:
        if browser is not None:
            browser.close()
        if run.poll() is None:
            run.send_signal(signal.SIGINT)  # the launcher stops its processes within a bounded time
            try:
                run.wait(120)
            except subprocess.TimeoutExpired:
                run.kill()
                run.wait(30)
