"""A real Rerun viewer beside the recorder: a headless viewer process and the web viewer.

Each test needs prerequisite ``snapshot`` (``report.snapshot.can_render``: the viewer and Mesa's
software Vulkan, .ci/install-snapshot-deps.sh): it skips without, fails so where
``FXSWARM_REQUIRE_SNAPSHOT=1`` (tests/prerequisites.py).
"""

from __future__ import annotations

import pytest

from fxswarm.cli import main as cli
from fxswarm.launch.launcher import free_port
from fxswarm.logger import style
from fxswarm.logger.recorder import RecorderOptions, SwarmRecorder
from fxswarm.logger.replay import world_states
from fxswarm.logger.sinks import open_recording, parse_outputs

from prerequisites import require
from support import RECORDED_S as DURATION, entities, has_colour, image_stats

pytestmark = pytest.mark.snapshot


@pytest.mark.slow
def test_file_grpc_and_web_outputs_at_once(live_run, scenario, tmp_path):
    """One recording to a file, a running (headless) viewer and the web viewer together."""
    import time
    import urllib.request

    from fxswarm.report.snapshot import viewer_binary

    require("snapshot")
    from rerun.experimental import ViewerClient

    port = free_port()
    viewer = ViewerClient.spawn(headless=True, port=port, hide_welcome_screen=True,
                                executable_path=str(viewer_binary()))
    try:
        # Plain `web`: a named port P needs P+1 free too, which a free_port() does not promise.
        outputs = parse_outputs(f"file,grpc=rerun+http://127.0.0.1:{port}/proxy,web", tmp_path)
        rec, said = open_recording(outputs, recording_id="test-outputs")
        assert any("web viewer" in line for line in said)
        recorder = SwarmRecorder(scenario, rec, RecorderOptions(link_health=False))
        recorder.start()
        _, traj, _ = live_run
        for state in list(world_states(traj))[::4]:
            recorder.frame(state)
        recorder.flush()
        rec.flush(timeout_sec=10)
        assert urllib.request.urlopen(f"http://127.0.0.1:{outputs.web_viewer_port}/", timeout=10).status == 200
        end = time.monotonic() + 20
        timelines = {}
        while time.monotonic() < end:
            for r in viewer.get_state().recordings:
                if r.store_id.endswith("test-outputs"):
                    timelines = {t.name: t.end for t in r.timelines}
            if timelines.get("sim_time") is not None and timelines["sim_time"] >= (DURATION - 0.1) * 1e9:
                break
            time.sleep(0.2)
        assert timelines.get("sim_time", 0) >= (DURATION - 0.1) * 1e9, timelines
        recorder.close()
        assert style.FORMATION_ERROR in entities(tmp_path / "recording.rrd")
    finally:
        viewer.quit()


@pytest.mark.slow
def test_snapshot_renders_the_default_blueprint_headless(run_dir):
    require("snapshot")
    assert cli(["report", str(run_dir), "--snapshot", "--times", "9"]) == 0
    shot = run_dir / "snapshots" / "view_9s.png"
    size, ink, colours = image_stats(shot)
    assert size == (1080, 1920)
    assert colours > 500
    from fxswarm.logger.style import robot_rgb

    # The robots and their curves are drawn, not just the empty layout (chunks fetched late).
    assert sum(has_colour(shot, robot_rgb(i), min_pixels=200) for i in range(6)) >= 4
    assert "snapshots/view_9s.png" in (run_dir / "index.md").read_text()
