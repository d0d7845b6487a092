"""The logger's recording, read back with Rerun's own reader, against trajectory.npz."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.messages import Estimate, LeaderState, WorldState
from fxswarm.core.metrics import estimate_errors, formation_errors
from fxswarm.logger import style
from fxswarm.logger.recorder import LinkHealth, RecorderOptions, SwarmRecorder
from fxswarm.logger.replay import record_run, world_states
from fxswarm.logger.sinks import OutputError, Outputs, open_recording, parse_outputs
from fxswarm.runtime.output import write_run
from fxswarm.launch.sim import Simulation
from fxswarm.core.scenario import directed_links

from support import PAPER_FAST, RECORDED_S as DURATION, entities, expected_entities, read_series, record_in_process


EXPECTED = expected_entities()


def test_live_recording_has_every_entity(live_run):
    rrd, _, _ = live_run
    assert EXPECTED <= entities(rrd)


def test_rate_limit_logs_one_frame_per_period(live_run, scenario):
    rrd, traj, recorder = live_run
    series = read_series(rrd)[style.FORMATION_ERROR]
    expected_t = np.arange(0, DURATION - 1e-9, 1 / 20.0)
    np.testing.assert_allclose(series["t"], expected_t, atol=1e-9)
    assert recorder.frames == len(expected_t)
    assert recorder.skipped == len(traj["t"]) - len(expected_t)


def _rows_at(traj_t: np.ndarray, times: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(traj_t, times - 1e-9)
    np.testing.assert_allclose(traj_t[idx], times, atol=1e-9)
    return idx


@pytest.mark.parametrize("sample", [0, 7, -1])
def test_logged_values_match_trajectory(live_run, sample):
    rrd, traj, _ = live_run
    series = read_series(rrd)
    t = series[style.FORMATION_ERROR]["t"]
    k = _rows_at(traj["t"], t)[sample]
    np.testing.assert_allclose(series[style.FORMATION_ERROR]["Scalars:scalars"][sample], formation_errors(traj)[k],
                               rtol=1e-6)
    np.testing.assert_allclose(series[style.ESTIMATE_ERROR]["Scalars:scalars"][sample], estimate_errors(traj)[k],
                               rtol=1e-6)
    near = series[style.NEAREST_DISTANCE]["Scalars:scalars"][sample]
    np.testing.assert_allclose(near[:-1], traj["nearest_distance"][k], rtol=1e-6)
    assert near[-1] == pytest.approx(2.0)  # the d line rides along as the last series
    positions = np.array(series[style.ROBOTS]["Points3D:positions"][sample])
    np.testing.assert_allclose(positions, traj["p"][k], atol=1e-4)  # stored as float32
    estimates = np.array(series[style.ESTIMATES]["Points3D:positions"][sample])
    np.testing.assert_allclose(estimates, traj["ph"][k], atol=1e-4)
    leader = np.array(series[style.LEADER]["Points3D:positions"][sample])
    np.testing.assert_allclose(leader[0], traj["p0"][k], atol=1e-4)
    assert series[style.AVOID_ACTIVE]["Scalars:scalars"][sample] == list(traj["avoid_active"][k].astype(float))


def test_links_are_healthy_in_a_fault_free_run(live_run):
    rrd, _, recorder = live_run
    series = read_series(rrd)
    assert np.all(np.array(series[style.LINK_STALE]["Scalars:scalars"]) == 0)
    assert np.all(np.array(series[style.LINK_DROPS]["Scalars:scalars"]) == 0)
    colours = np.array(series[style.EDGES]["LineStrips3D:colors"])
    assert np.all(colours == style.LINK_OK)
    assert recorder.counters()["link_drops_seen"] == 0
    rtf = np.array(series[style.REAL_TIME_FACTOR]["Scalars:scalars"]).ravel()
    assert len(rtf) > 0 and np.all(rtf > 0)


def test_replay_of_a_run_folder_matches_the_live_recording(live_run, scenario, tmp_path):
    rrd, traj, _ = live_run
    out = record_run(rrd.parent, tmp_path / "replay.rrd", scenario=scenario,
                     options=RecorderOptions(rate_hz=20.0, link_health=False))
    live, replay = read_series(rrd), read_series(out)
    for entity in (style.FORMATION_ERROR, style.ESTIMATE_ERROR, style.NEAREST_DISTANCE):
        np.testing.assert_array_equal(live[entity]["t"], replay[entity]["t"])
        np.testing.assert_allclose(live[entity]["Scalars:scalars"], replay[entity]["Scalars:scalars"])
    assert style.LINK_STALE not in replay  # a trajectory says nothing about links


def test_replay_finds_the_scenario_from_the_summary(tmp_path, scenario):
    sim = Simulation(dataclasses.replace(scenario, duration=0.5))
    write_run(tmp_path, sim.run(), sim.trajectory())  # summary's source: configs/paper-fast.toml
    import os
    cwd = os.getcwd()
    os.chdir(PAPER_FAST.parents[1])
    try:
        path = record_run(tmp_path)
    finally:
        os.chdir(cwd)
    assert path == tmp_path / "recording.rrd"
    assert style.FORMATION_ERROR in entities(path)


def _state(sc, tick: int, age, drops) -> WorldState:
    n = sc.n
    z = np.zeros((n, 3))
    return WorldState("world", 0, tick + 1, tick, tick * sc.dt, z, z, z, np.ones(n), np.zeros(n, bool),
                      np.zeros((0, 3)), np.asarray(age, dtype=np.int64), np.asarray(drops, dtype=np.int64))


def test_link_health_from_the_robots_reports_per_edge(scenario):
    links = LinkHealth(scenario)
    assert links.names[:2] == ["1-2", "1-6"] and links.names[-2:] == ["L-1", "L-4"]
    directed = directed_links(scenario)
    zero = np.zeros(len(directed), dtype=np.int64)
    bad, drops, stale = links.at(_state(scenario, 0, zero, zero), stale_ticks=2, recent_drop_s=1.0)
    assert not bad.any() and not drops.any() and not stale.any()
    # Robot 3 missed two of robot 2's estimates (2 -> 3 only); robot 4's leader estimate is 5 ticks old.
    age, dropped = zero.copy(), zero.copy()
    dropped[directed.index((2, 3))] = 2
    age[directed.index((0, 4))] = 5
    bad, drops, stale = links.at(_state(scenario, 4, age, dropped), stale_ticks=2, recent_drop_s=1.0)
    by_name = dict(zip(links.names, zip(bad, drops, stale)))
    assert by_name["2-3"] == (True, 2, 0) and by_name["L-4"] == (True, 0, 1)
    assert not any(b for name, (b, _, _) in by_name.items() if name not in ("2-3", "L-4"))
    # A drop stays red for recent_drop_s; the count stays.
    bad, drops, _ = links.at(_state(scenario, 200, zero, dropped), stale_ticks=2, recent_drop_s=1.0)
    assert not bad.any() and drops[links.names.index("2-3")] == 2
    # The other direction 3 -> 2 ages: the undirected edge is stale if either direction is.
    age = zero.copy()
    age[directed.index((3, 2))] = 3
    bad, _, stale = links.at(_state(scenario, 201, age, dropped), stale_ticks=2, recent_drop_s=1.0)
    assert bad[links.names.index("2-3")] and bad.sum() == 1 and stale[links.names.index("2-3")] == 1


def test_recorder_ignores_estimates_and_takes_world_states(scenario, tmp_path):
    rec, _ = open_recording(Outputs(file=tmp_path / "r.rrd"), recording_id="t")
    recorder = SwarmRecorder(scenario, rec)
    assert not recorder.take("agent/1/estimate", Estimate("agent", 1, 1, 0, 0.0, 1, np.zeros(3)))
    assert not recorder.take("leader/state", LeaderState("leader", 0, 1, 0, 0.0, np.zeros(3)))
    assert recorder.frames == 0
    state = next(world_states(_one_tick_trajectory(scenario)))
    assert recorder.take("world/state", state) and recorder.frames == 1
    assert not recorder.take("world/state", state)  # same time again: inside the rate period
    assert recorder.links.unreported == 1  # rebuilt from a trajectory: no link report
    recorder.close()


def test_recorder_subscribes_to_the_world_state_only():
    from fxswarm.core import bus as topics
    from fxswarm.logger.recorder import RECORDER_TOPICS

    assert RECORDER_TOPICS == (topics.WORLD_STATE,)


def test_a_drop_at_a_receivers_inbox_shows_on_that_edge_in_the_recording(tmp_path):
    """A partition cutting robot 2's estimates at robot 3's inbox for 1 s: the recording's drop
    series for edge 2-3 ends at the inbox's drop count, every other edge at 0, and 2-3 alone is red."""
    import tomllib

    from fxswarm.core.scenario import parse

    data = tomllib.loads(PAPER_FAST.read_text())
    data["scenario"]["duration"] = 3.0
    data["faults"] = {"partitions": [{"start": 1.0, "end": 2.0, "links": ["agent:2->agent:3"], "kinds": ["estimate"]}]}
    sc = parse(data, "paper-fast.toml+partition")
    rrd = tmp_path / "partition.rrd"
    sim, summary, recorder = record_in_process(sc, rrd, "test-partition", RecorderOptions(rate_hz=20.0))
    dropped = summary["faults"]["links"]["agent:2->agent:3/estimate"]["dropped"]
    assert dropped == 100
    series = read_series(rrd)
    names = recorder.links.names
    e = names.index("2-3")
    drops = np.array(series[style.LINK_DROPS]["Scalars:scalars"])  # (frames, edges)
    assert drops[-1, e] == dropped and np.delete(drops[-1], e).sum() == 0
    t = series[style.LINK_DROPS]["t"]
    assert drops[t < 1.0, e].max() == 0
    stale = np.array(series[style.LINK_STALE]["Scalars:scalars"])
    assert stale[-1, e] > 10 and np.delete(stale[-1], e).sum() == 0
    colours = np.array(series[style.EDGES]["LineStrips3D:colors"])  # (frames, edges)
    during = (t > 1.1) & (t < 1.9)
    assert np.all(colours[during, e] == style.LINK_BAD)
    assert np.all(np.delete(colours, e, axis=1) == style.LINK_OK)
    assert np.all(colours[t < 0.99, e] == style.LINK_OK)


def _one_tick_trajectory(sc):
    sim = Simulation(dataclasses.replace(sc, duration=sc.dt * 2))
    sim.run()
    return sim.trajectory()


def test_parse_outputs(tmp_path):
    o = parse_outputs("file,grpc,web=9000", tmp_path)
    assert o.file == tmp_path / "recording.rrd" and o.grpc.startswith("rerun+http://") and o.web_port == 9000
    assert parse_outputs("file=x.rrd", tmp_path).file == Path("x.rrd")
    with pytest.raises(OutputError, match="'viewer'"):
        parse_outputs("file,viewer", tmp_path)
    with pytest.raises(OutputError, match="names no output"):
        parse_outputs(",", tmp_path)


def test_options_from_scenario_logging_table(scenario):
    """Defaults, then [logging] (checked with the scenario: tests/unit/test_core_scenario.py),
    then the command line's overrides."""
    sc = dataclasses.replace(scenario, logging={"rate_hz": 5.0, "velocities": True, "trail_s": 9.0})
    opts = RecorderOptions.from_scenario(sc, rate_hz=None, trail_s=3.0)
    assert opts.rate_hz == 5.0 and opts.velocities and opts.trail_s == 3.0
    assert opts.trail_dt == RecorderOptions.trail_dt
    assert RecorderOptions.from_scenario(sc, rate_hz=2.0).rate_hz == 2.0


def test_moving_obstacles_move_in_the_recording(scenario, tmp_path):
    from fxswarm.core import motion

    moving = motion.ConstantVelocity((0.0, 0.0, 5.0), (0.5, 0.0, 0.0))
    sc = dataclasses.replace(scenario, duration=1.0, obstacles=(moving, *scenario.obstacles[1:]))
    rrd = tmp_path / "moving.rrd"
    sim, _, recorder = record_in_process(sc, rrd, "test-moving", RecorderOptions(rate_hz=10.0))
    traj = sim.trajectory()
    series = read_series(rrd)[style.OBSTACLES]
    k = _rows_at(traj["t"], series["t"])
    centres = np.array(series["Ellipsoids3D:centers"])
    np.testing.assert_allclose(centres, traj["obstacles"][k], atol=1e-4)
    assert centres[-1, 0, 0] > centres[0, 0, 0] + 0.4  # it moved along x
