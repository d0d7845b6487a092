"""Helpers the test layers share (fixtures are in ``conftest.py``; the swarm harness is
``fxswarm.testing``). On ``sys.path`` through ``pythonpath`` in pyproject.toml."""

from __future__ import annotations

import contextlib
import fcntl
import socket
import sys
import tomllib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
PAPER_FAST = CONFIGS / "paper-fast.toml"
PAPER = CONFIGS / "paper.toml"
#: Every scenario the project ships, by stem (``paper-fast``, ``faults-crash``, ...).
SHIPPED_CONFIGS = sorted(CONFIGS.glob("*.toml"))

#: A fault plan that acts within a 1.5 s run of paper-fast: loss, delay (carried forward at the
#: observed velocity), duplicates, a partition (robot 3 hears nobody: extrapolation) and a
#: leader outage. For lock-step-equals-sim tests under faults.
SHORT_RUN_FAULTS = {
    "seed": 5,
    "links": [
        {"link": "agent:*->agent:*", "kinds": ["estimate"], "drop": 0.2, "delay": 0.03, "jitter": 0.02,
         "duplicate": 0.1},
        {"link": "leader->agent:1", "drop": 0.3, "delay": 0.01},
    ],
    "partitions": [{"start": 0.6, "end": 0.9, "isolate": [3]}],
    "leader_outages": [{"start": 1.0, "end": 1.2}],
}


def finish_faulted_lockstep_run(swarm) -> dict:
    """Wait for a lock-step run under :data:`SHORT_RUN_FAULTS` to end and check what every such
    run must show: bit for bit the sim's, no missed tick, the same degraded ticks as the sim,
    and the partition seen (robot 3 extrapolating). Returns the run's summary."""
    summary = swarm.wait_done(timeout=180)
    expected = swarm.assert_matches_sim()
    assert summary["complete"] and summary["missed_ticks"] == 0
    assert summary["faults"]["degraded_ticks"] == expected["faults"]["degraded_ticks"]
    assert summary["faults"]["degraded_ticks"]["extrapolating"].get("3", 0) > 0  # the partition bit
    return summary


#: Length of the recorded runs (conftest's ``scenario``), s: formation motion, no avoidance yet.
RECORDED_S = 3.0


def copy_source(dest: Path) -> Path:
    """Copy the project's source tree (no venv, caches, runs or builds) to ``dest``; return it.
    A build writes build/ and *.egg-info beside the sources: done on a copy, it leaves the
    working tree (and a concurrent `make lint`, which builds there) alone."""
    import shutil

    shutil.copytree(REPO, dest, ignore=shutil.ignore_patterns(
        ".git", ".venv", "runs", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache", ".hypothesis",
        ".import_linter_cache", "results"))
    return dest


def stop_processes(procs) -> None:
    """SIGTERM every process of ``procs`` still running, then wait for each (SIGKILL after 30 s)."""
    import subprocess

    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def wait_for_line(log: Path, needle: str, running=(), timeout: float = 60.0) -> str:
    """Wait until the file ``log`` says ``needle`` while every process in ``running`` still runs;
    return that line."""
    import time

    deadline = time.monotonic() + timeout
    while True:
        for line in log.read_text().splitlines():
            if needle in line:
                return line
        assert time.monotonic() < deadline, f"{log.name} never said {needle!r}: {log.read_text()[-2000:]}"
        assert all(p.poll() is None for p in running), f"{log.name}: {log.read_text()[-2000:]}"
        time.sleep(0.05)


def fxswarm_command(*args: str) -> list[str]:
    """The command line of ``fxswarm ARGS...`` with this interpreter (the source tree's fxswarm)."""
    return [sys.executable, "-m", "fxswarm.cli", *map(str, args)]


#: A vector any message may carry (m or m/s).
V = np.array([1.0, 2.0, 3.0])


def estimate(robot: int, sender: int | None = None, tick: int = 0):
    """An ``Estimate`` on robot ``robot``'s key, signed by ``sender`` (default: itself), ph = :data:`V`."""
    from fxswarm.core.messages import Estimate

    return Estimate("agent", robot if sender is None else sender, 1, tick, 0.0, robot, V)


# Every kind of link fault at once, strong enough to act within a short run (paper-fast, 1.5 s).
MIXED_FAULTS = {
    "seed": 11,
    "links": [
        {"link": "agent:*->agent:*", "kinds": ["estimate"], "drop": 0.2, "delay": 0.03, "jitter": 0.02,
         "duplicate": 0.1, "reorder": 0.1},
        {"link": "agent:2->agent:3", "burst": {"p_good_bad": 0.05, "p_bad_good": 0.3}},
        {"link": "leader->agent:1", "drop": 0.3, "delay": 0.01},
        {"link": "world->agent:5", "kinds": ["sense"], "drop": 0.2},
        {"link": "agent:6->world", "kinds": ["command"], "drop": 0.1},
    ],
    "partitions": [{"start": 0.6, "end": 0.9, "isolate": [3]}],
    "leader_outages": [{"start": 1.0, "end": 1.2}],
}


def with_faults(faults: dict, **scenario):
    """paper-fast with ``[faults]`` = ``faults`` and ``[scenario]`` keys overridden, parsed."""
    from fxswarm.core.scenario import parse

    data = tomllib.loads(PAPER_FAST.read_text())
    data["scenario"].update(scenario)
    data["faults"] = faults
    return parse(data, "paper-fast.toml+faults")


def ring_scenario(folder: Path, robots: int) -> Path:
    """A copy of paper-fast with ``robots`` robots on a ring (offsets spread on a circle)."""
    import math

    text = PAPER_FAST.read_text()
    head = text[: text.index("[[robots]]")]
    tail = text[text.index("[[obstacles]]"):]
    rows = []
    for k in range(robots):
        a = 2 * math.pi * k / robots
        rows.append(f"[[robots]]\nposition = [{8 * math.cos(a):.3f}, {8 * math.sin(a):.3f}, 0.0]\n"
                    f"offset = [{3 * math.cos(a):.3f}, {3 * math.sin(a):.3f}, 0.0]\n")
    path = Path(folder) / f"ring{robots}.toml"
    head = head.replace('name = "paper-fast"', f'name = "ring{robots}"')
    head = head.replace("pinned = [1, 4]", "pinned = [1]")
    path.write_text(head + "".join(rows) + "\n" + tail)
    return path


# --- Rerun recordings, read back with Rerun's own reader -----------------------------------------


def read_series(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """Per entity: ``t`` (s) and each component's values (rows stacked), temporal rows only."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        if "sim_time" not in batch.schema.names:
            continue
        entity = out.setdefault(chunk.entity_path.lstrip("/"), {})
        times = batch.column("sim_time").cast("int64").to_numpy() / 1e9
        entity.setdefault("t", []).extend(times)
        for name in batch.schema.names:
            if ":" in name:
                entity.setdefault(name, []).extend(batch.column(name).to_pylist())
    result = {}
    for entity, cols in out.items():
        order = np.argsort(cols["t"], kind="stable")
        result[entity] = {k: [v[i] for i in order] if k != "t" else np.asarray(v)[order] for k, v in cols.items()}
    return result


def entities(path: Path) -> set[str]:
    """Every entity path in the recording at ``path``."""
    from rerun.chunk import RrdReader

    return {chunk.entity_path.lstrip("/") for chunk in RrdReader(path).stream()}


def expected_entities() -> set[str]:
    """What the logger draws for a run (velocities only when asked for)."""
    from fxswarm.logger import style

    return {style.ROBOTS, style.TRAILS, style.LEADER, style.ESTIMATES, style.SLOTS, style.OBSTACLES, style.EDGES,
            style.VELOCITIES, style.FORMATION_ERROR, style.NEAREST_DISTANCE, style.ESTIMATE_ERROR,
            style.AVOID_ACTIVE, style.LINK_DROPS, style.LINK_STALE, style.REAL_TIME_FACTOR, style.TICK_RATE}


def record_in_process(sc, rrd: Path, recording_id: str, options):
    """Run ``sc`` in the in-process simulator with a recorder on its bus writing ``rrd``;
    return (simulation, summary, recorder). ``options``: a ``RecorderOptions``."""
    from fxswarm.launch.sim import Simulation
    from fxswarm.logger.recorder import SwarmRecorder, attach
    from fxswarm.logger.sinks import Outputs, open_recording

    sim = Simulation(sc)
    rec, _ = open_recording(Outputs(file=rrd), recording_id=recording_id)
    recorder = SwarmRecorder(sc, rec, options)
    recorder.start()
    attach(sim.bus, recorder)
    summary = sim.run()
    recorder.close()
    return sim, summary, recorder


# --- figures -----------------------------------------------------------------------------------

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def image_stats(path: Path) -> tuple[tuple[int, int], float, int]:
    """(size (h, w), fraction of non-background pixels, number of distinct colours)."""
    import matplotlib.image as mpimg

    assert path.read_bytes()[:8] == PNG_MAGIC, f"{path} is not a PNG"
    img = mpimg.imread(path)[..., :3]
    background = np.median(img.reshape(-1, 3), axis=0)
    ink = np.any(np.abs(img - background) > 0.1, axis=2).mean()
    rgb = (img * 255).astype(np.uint32)
    colours = len(np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]))
    return img.shape[:2], float(ink), colours


def has_colour(path: Path, rgb: int, tol: int = 25, min_pixels: int = 30) -> bool:
    """Whether at least ``min_pixels`` pixels of the PNG at ``path`` are within ``tol`` of ``rgb``."""
    import matplotlib.image as mpimg

    img = (mpimg.imread(path)[..., :3] * 255).astype(int)
    target = np.array([(rgb >> 16) & 255, (rgb >> 8) & 255, rgb & 255])
    return int((np.abs(img - target).max(axis=2) <= tol).sum()) >= min_pixels


def measured(test: str, **values) -> None:
    """Print one line of the figures a real-time bound is judged on (``MEASURED test k=v ...``):
    run with ``-s`` (or ``-rP``), the lines of many runs give the distribution written beside the
    bound (docs/testing.md "Real-time bounds")."""
    print("MEASURED", test, " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                     for k, v in values.items()), flush=True)


@contextlib.contextmanager
def once_per_session(tmp_path_factory, worker_id: str, name: str):
    """A path (``name``, not created) that every pytest-xdist worker of this session shares, held
    under a lock while the block runs: the first worker to enter makes what belongs there, the
    others find it made."""
    base = tmp_path_factory.getbasetemp()
    path = (base if worker_id == "master" else base.parent) / name  # a worker's parent: the session's
    with open(f"{path}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield path


@contextlib.contextmanager
def port_nobody_listens_on():
    """A local TCP port where a connection is refused, held (bound, never listening) for the
    block: free_port() would name one that a test on another pytest-xdist worker can be handed and
    start a router on meanwhile (an attach that must wait for its router once reached theirs)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", 0))
        yield held.getsockname()[1]
