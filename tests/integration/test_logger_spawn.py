"""``--rerun spawn`` without a display: a fake ``rerun`` first on PATH stands in for the viewer.

rerun-sdk's spawn runs the ``rerun`` executable it finds on PATH (``rerun --version``, then
``rerun --port=9876 ...``) and waits until something listens on the port; the fake records its
arguments and pid, listens, and is stopped by the test.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import sys

import pytest

from fxswarm.core.scenario import load
from fxswarm.logger import style
from fxswarm.logger.recorder import RecorderOptions, SwarmRecorder
from fxswarm.logger.replay import world_states
from fxswarm.logger.sinks import DEFAULT_GRPC, open_recording, parse_outputs
from fxswarm.launch.sim import Simulation

from support import PAPER_FAST, read_series


PORT = 9876  # rr.spawn's default, which the logger uses

FAKE_RERUN = f"""#!{sys.executable}
import os, socket, sys, time
log = os.environ["FAKE_RERUN_LOG"]
with open(log, "a") as f:
    f.write(f"{{os.getpid()}} " + " ".join(sys.argv[1:]) + "\\n")
if "--version" in sys.argv:
    print("rerun-cli 0.41.0")
    sys.exit(0)
s = socket.socket()
s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind(("127.0.0.1", {PORT}))
s.listen(16)
s.settimeout(0.1)
conns = []
end = time.monotonic() + 30  # never outlives a broken test for long
while time.monotonic() < end:
    try:
        conns.append(s.accept()[0])
    except socket.timeout:
        pass
"""


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_spawn_output_starts_the_rerun_on_path_and_still_writes_the_file(tmp_path, monkeypatch):
    if not _port_free(PORT):
        pytest.skip(f"port {PORT} is taken: rerun would take whatever listens there for a viewer")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "rerun"
    fake.write_text(FAKE_RERUN)
    fake.chmod(0o755)
    log = tmp_path / "fake-rerun.log"
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_RERUN_LOG", str(log))
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.delenv("_RERUN_TEST_FORCE_SAVE", raising=False)

    outputs = parse_outputs("file,spawn", tmp_path)
    assert outputs.spawn and outputs.grpc is None
    started = []
    try:
        rec, said = open_recording(outputs, recording_id="test-spawn")  # returns once the fake listens
        started = [line.split() for line in log.read_text().splitlines()]
        assert "spawned a local viewer" in said
        viewer = [args for args in started if "--version" not in args]
        assert len(viewer) == 1, started
        assert f"--port={PORT}" in viewer[0], viewer[0]
        sc = dataclasses.replace(load(PAPER_FAST), duration=0.2)
        sim = Simulation(sc)
        sim.run()
        recorder = SwarmRecorder(sc, rec, RecorderOptions(link_health=False))
        recorder.start()
        for state in world_states(sim.trajectory()):
            recorder.take("world/state", state)
        assert recorder.frames == 5
    finally:
        lines = log.read_text().splitlines() if log.exists() else []
        for line in lines:  # the fake viewer is detached from us: stop it by the pid it wrote
            try:
                os.kill(int(line.split()[0]), signal.SIGTERM)
            except ProcessLookupError:
                pass
    recorder.close(timeout_s=5.0)  # the "viewer" is gone: noted, not raised, and the file is whole
    assert recorder.sink_error is None or "9876" in recorder.sink_error
    assert len(read_series(tmp_path / "recording.rrd")[style.FORMATION_ERROR]["t"]) == 5
    assert DEFAULT_GRPC.endswith(f":{PORT}/proxy")  # where the logger streams after spawning
