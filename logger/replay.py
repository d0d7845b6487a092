"""A recording from a finished run folder (``trajectory.npz`` + the scenario), through the same recorder.

``fxswarm sim`` writes no recording while it runs (it is the fast path);
this turns its output into one. The frames are the world states the run
went through, rebuilt from the trajectory: the same values the live logger
would have logged, at the same rate.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxswarm.core.messages import WorldState
from fxswarm.core.scenario import Scenario, load
from fxswarm.logger.recorder import RecorderOptions, SwarmRecorder
from fxswarm.logger.sinks import Outputs, open_recording
from fxswarm.runtime.output import load_trajectory, scenario_of_run


def world_states(traj: dict[str, np.ndarray]):
    """The ``WorldState`` of every recorded tick, as the world node publishes it."""
    near = np.where(np.isfinite(traj["nearest_distance"]), traj["nearest_distance"], -1.0)
    heading = traj.get("heading")  # unicycles' (docs/robots.md)
    for k, t in enumerate(traj["t"]):
        yield WorldState("world", 0, k + 1, k, float(t), traj["p"][k], traj["v"][k], traj["ph"][k], near[k],
                         traj["avoid_active"][k], traj["obstacles"][k],
                         heading=None if heading is None else heading[k])


def record_run(run_dir: str | Path, out: str | Path | None = None, scenario: Scenario | None = None,
               options: RecorderOptions | None = None) -> Path:
    """Write ``out`` (default ``<run_dir>/recording.rrd``) from the run's trajectory; return its path."""
    run = Path(run_dir)
    sc = scenario or scenario_of_run(run)
    traj = load_trajectory(run)
    path = Path(out) if out is not None else run / "recording.rrd"
    rec, _ = open_recording(Outputs(file=path), recording_id=f"{sc.name}-{run.name}")
    opts = options or RecorderOptions.from_scenario(sc, flush_frames=500, flush_wall_s=1e9, link_health=False)
    recorder = SwarmRecorder(sc, rec, opts)
    recorder.start()
    for state in world_states(traj):
        if recorder.due(state.t):
            recorder.frame(state)
        else:
            recorder.skipped += 1
    recorder.close()
    return path
