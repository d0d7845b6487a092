"""The logger at 1 000 robots: a recording is written and its last frame holds every robot.

A regression in scale shows here twice: a per-robot Python call per frame (the desired slots
were once computed so) fails the call count, and a recording that loses or mixes robots fails
the positions. The recorder's CPU per frame by N: benchmarks/bench_logger_scale.py.
"""

from __future__ import annotations

import tomllib

import numpy as np

from fxswarm.core import motion
from fxswarm.core.scenario import parse
from fxswarm.launch.sim import Simulation
from fxswarm.logger import style
from fxswarm.logger.recorder import RecorderOptions, SwarmRecorder
from fxswarm.logger.replay import world_states
from fxswarm.logger.sinks import Outputs, open_recording

from support import CONFIGS, read_series

N = 1000


def _swarm(n: int, duration: float):
    """configs/examples/swarm/swarm-n.toml at ``n`` robots, its slots swaying (a moving offset)."""
    path = CONFIGS / "examples" / "swarm" / "swarm-n.toml"
    data = tomllib.loads(path.read_text())
    data["swarm"]["count"] = n
    data["scenario"]["duration"] = duration
    data["formation"] = {"amplitude": [0.5, 0.0, 0.2], "omega": [2.0, 0.0, 3.0]}
    return parse(data, f"{path.name}+count={n}")


def test_a_1000_robot_recording_holds_every_robot_in_its_last_frame(tmp_path, monkeypatch):
    sc = _swarm(N, duration=0.3)
    sim = Simulation(sc, path="batch")
    sim.run()
    traj = sim.trajectory()
    calls = []
    real = motion.Offset.state_lists
    monkeypatch.setattr(motion.Offset, "state_lists", lambda self, t: (calls.append(t), real(self, t))[1])
    rrd = tmp_path / "n1000.rrd"
    rec, _ = open_recording(Outputs(file=rrd), recording_id="test-n1000")
    recorder = SwarmRecorder(sc, rec, RecorderOptions(rate_hz=10.0, link_health=False))
    recorder.start()
    for state in world_states(traj):
        recorder.take("world/state", state)
    recorder.close()
    assert calls == []  # no call per robot: the slots come from arrays
    monkeypatch.undo()

    series = read_series(rrd)
    robots = series[style.ROBOTS]
    np.testing.assert_allclose(robots["t"], [0.0, 0.1, 0.2], atol=1e-9)
    k = int(np.argmin(np.abs(traj["t"] - robots["t"][-1])))
    last = np.array(robots["Points3D:positions"][-1])
    assert last.shape == (N, 3)
    np.testing.assert_allclose(last, traj["p"][k], atol=1e-4)  # float32 in the recording
    assert not np.allclose(last, traj["p"][0], atol=1e-3)  # the robots moved: not the first frame again
    t = float(traj["t"][k])
    slots = np.array(series[style.SLOTS]["Points3D:positions"][-1])
    expected = sc.leader.position(t) + np.array([r.offset.position(t) for r in sc.robots])
    np.testing.assert_allclose(slots, expected, atol=1e-4)
    errors = np.array(series[style.FORMATION_ERROR]["Scalars:scalars"][-1])
    np.testing.assert_allclose(errors, np.linalg.norm(traj["p"][k] - expected, axis=1), rtol=1e-9)
    trails = series[style.TRAILS]["LineStrips3D:strips"][-1]
    assert len(trails) == N
    np.testing.assert_allclose([strip[-1] for strip in trails], traj["p"][k], atol=1e-4)
    edges = series[style.EDGES]["LineStrips3D:strips"][-1]
    assert len(edges) == len(recorder.links.edges) > N  # k-nearest (4) plus the leader's links
