"""The logger as a process on the Zenoh bus, started by the launcher beside the swarm."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.metrics import formation_errors
from fxswarm.logger import style
from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import scenario_with

from support import PAPER_FAST, entities, expected_entities, fxswarm_command, read_series


@pytest.mark.zenoh
def test_launcher_runs_the_logger_and_its_recording_matches_the_trajectory(launch_swarm):
    swarm = launch_swarm(PAPER_FAST, logger=True, duration=2.0)
    summary = swarm.wait_done(timeout=120)
    rrd = swarm.out / "recording.rrd"
    assert rrd.is_file(), "the logger left no recording"
    logger = summary["processes"]["logger-0"]
    assert logger["stop_reason"] == "run over", logger
    assert logger["invalid"] == 0
    assert logger["logger"]["nice"] >= 10  # the swarm's processes first, on a busy machine
    # Nothing dropped on a quiet machine, and whatever was dropped is counted, not lost silently.
    frames = logger["logger"]["frames"]
    ticks = summary["ticks"]
    assert frames + logger["logger"]["skipped_by_rate"] + logger["dropped"] >= ticks
    assert frames >= 0.9 * 2.0 * 25  # 25 Hz of simulation time, default rate

    assert expected_entities() - {style.VELOCITIES} <= entities(rrd)
    traj = load_trajectory(swarm.out)
    series = read_series(rrd)
    t = series[style.FORMATION_ERROR]["t"]
    k = np.searchsorted(traj["t"], t - 1e-9)
    np.testing.assert_allclose(traj["t"][k], t, atol=1e-9)
    np.testing.assert_allclose(np.array(series[style.FORMATION_ERROR]["Scalars:scalars"]), formation_errors(traj)[k],
                               rtol=1e-6)
    np.testing.assert_allclose(np.array(series[style.ROBOTS]["Points3D:positions"]), traj["p"][k], atol=1e-4)
    # No message was lost on the way, so no link ever showed a drop; and when every tick closed
    # with every command (no tick timed out on an overloaded machine), no estimate was stale.
    assert np.all(np.array(series[style.LINK_DROPS]["Scalars:scalars"]) == 0)
    if summary["missed_ticks"] == 0:
        assert np.all(np.array(series[style.LINK_STALE]["Scalars:scalars"]) == 0)
    assert len(series[style.TICK_RATE]["Scalars:scalars"]) > 0


@pytest.mark.zenoh
def test_the_logger_process_shows_a_drop_made_at_a_receivers_inbox(launch_swarm):
    """Over Zenoh, robot 3's inbox drops robot 2's estimates for 0.5 s (a partition of 2 -> 3):
    the logger, which hears only world/state, records exactly those drops on edge 2-3."""
    swarm = launch_swarm(PAPER_FAST, logger=True, duration=1.5,
                         **{"faults.partitions": [{"start": 0.5, "end": 1.0, "links": ["agent:2->agent:3"],
                                                   "kinds": ["estimate"]}]})
    summary = swarm.wait_done(timeout=120)
    dropped = summary["faults"]["links"]["agent:2->agent:3/estimate"]["dropped"]
    assert dropped == 50
    logger = summary["processes"]["logger-0"]
    assert logger["logger"]["link_drops_seen"] == dropped and logger["logger"]["link_unreported_frames"] == 0
    series = read_series(swarm.out / "recording.rrd")
    drops = np.array(series[style.LINK_DROPS]["Scalars:scalars"])  # (frames, edges)
    names = ["1-2", "1-6", "2-3", "3-4", "4-5", "5-6", "L-1", "L-4"]  # paper-fast: a ring, 1 and 4 pinned
    e = names.index("2-3")
    assert drops.shape[1] == len(names)
    assert drops[-1, e] == dropped and np.delete(drops[-1], e).sum() == 0


def fxswarm_run(config: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    """``fxswarm run CONFIG --out OUT EXTRA...`` as a user types it."""
    return subprocess.run(fxswarm_command("run", config, "--out", out, *extra),
                          capture_output=True, text=True, timeout=240)


@pytest.mark.zenoh
def test_fxswarm_run_names_what_it_wrote_and_how_to_view_the_recording(tmp_path):
    """What `make run` prints at the end: the summary, the trajectory and this run's recording."""
    config = scenario_with(PAPER_FAST, tmp_path, duration=1.0)
    out = tmp_path / "run"
    out.mkdir()
    (out / "recording.rrd").write_bytes(b"an earlier run's")

    def run(*extra: str) -> str:
        done = fxswarm_run(config, out, *extra)
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout

    said = run("--no-logger")  # the stale recording is not announced as this run's
    assert f"wrote {out}/summary.json and {out}/trajectory.npz" in said and "recording.rrd" not in said, said
    said = run()
    assert f"wrote {out}/recording.rrd (view it: rerun {out}/recording.rrd" in said, said
    assert (out / "recording.rrd").stat().st_size > 1000


@pytest.mark.zenoh
def test_fxswarm_run_passes_its_rerun_outputs_to_the_logger(tmp_path):
    config = scenario_with(PAPER_FAST, tmp_path, duration=1.0)
    live = tmp_path / "elsewhere" / "live.rrd"
    live.parent.mkdir()
    done = fxswarm_run(config, tmp_path / "run", "--rerun", f"file={live}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"wrote {live} (view it: rerun {live};" in done.stdout, done.stdout
    assert live.stat().st_size > 1000 and not (tmp_path / "run" / "recording.rrd").exists()


@pytest.mark.parametrize("extra, said", [
    (["--rerun", "file,bogus"], "--rerun 'bogus': expected a comma-separated list of"),
    (["--rerun", "spawn", "--no-logger"], "--rerun sets the logger's outputs; it cannot go with --no-logger"),
])
def test_fxswarm_run_refuses_wrong_rerun_outputs_before_starting_anything(tmp_path, extra, said):
    done = fxswarm_run(PAPER_FAST, tmp_path, *extra)
    assert done.returncode == 2 and said in done.stderr, done.stderr
    assert not (tmp_path / "logs").exists()  # no process was started
