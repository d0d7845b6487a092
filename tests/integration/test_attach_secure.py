"""``fxswarm attach --secure``: a secure run observed from outside its processes, through the router.

A secure lock-step run (``fxswarm run --secure`` as the launcher starts it) whose world waits for the
observer's token; ``fxswarm attach --secure KEYS`` as its own process, showing the observer's
certificate, takes the scenario from the router and rebuilds the world's own trajectory. A key of
another CA gets no session and says so.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.scenario import load
from fxswarm.security.keys import write_keys

pytestmark = [pytest.mark.zenoh, pytest.mark.timeout(600)]

REPO = Path(__file__).resolve().parents[2]
SCENARIO = REPO / "configs" / "paper-fast.toml"


def attach(swarm, keys: Path, out: Path, log: Path, timeout: float) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fxswarm.cli", "attach", swarm.swarm.endpoint,
                             "--swarm", swarm.swarm.swarm, "--out", str(out), "--secure", str(keys),
                             "--timeout", str(timeout), "--quiet"],
                            stdout=log.open("w"), stderr=subprocess.STDOUT)


@pytest.mark.slow
def test_secure_attach_writes_the_worlds_trajectory_and_another_ca_is_refused(launch_swarm, tmp_path):
    keys, other = tmp_path / "keys", tmp_path / "other-keys"
    write_keys(keys, load(SCENARIO))
    write_keys(other, load(SCENARIO))  # another CA of the same name
    swarm = launch_swarm(SCENARIO, secure=keys, duration=4.0, start=False, world_args=("--wait-for", "observer/0"))
    seen, log = tmp_path / "seen", tmp_path / "attach.log"
    stranger_log = tmp_path / "stranger.log"
    procs = [attach(swarm, keys, seen, log, timeout=240)]  # waits for the router, which start() brings up
    try:
        swarm.start(timeout=240)  # the world starts its clock once the observer's token is up
        procs.append(attach(swarm, other, tmp_path / "stranger", stranger_log, timeout=3))
        assert procs[1].wait(120) != 0, stranger_log.read_text()
        swarm.wait_done(timeout=300)
        code = procs[0].wait(120)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(10)
    said = log.read_text()
    assert code == 0, said
    # Refused at the TLS handshake: no session, nothing written, and a line that says why.
    refused = stranger_log.read_text()
    assert "it answers, but the TLS handshake failed" in refused and str(other / "observer.pem") in refused, refused
    assert not (tmp_path / "stranger" / "trajectory.npz").exists()
    assert (seen / "scenario.toml").read_text() == Path(swarm.swarm.config).read_text(), "asked of the router"
    with np.load(swarm.out / "trajectory.npz") as a, np.load(seen / "trajectory.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            assert np.array_equal(a[key], b[key]), key
    mine = json.loads((seen / "summary.json").read_text())
    assert mine["complete"] and mine["states_missed"] == 0 and mine["restarts"] == {}, mine
    assert mine["record"]["from"] == "world", mine["record"]  # the rules let the observer ask the world
    # The recording too: rerun-sdk is in .[dev] (fxswarm[logger]), so no branch on whether it imports.
    assert (seen / "recording.rrd").stat().st_size > 10_000
