"""The Rerun recorder's CPU per logged frame by swarm size (N = 30, 300, 1 000 by default).

For each N: a generated swarm (configs/examples/swarm/swarm-n.toml, ``swarm.count = N``, a
static leader, so the slots are still) is flown for ``--seconds`` simulated seconds on the
batch path; its world states (the messages the logger would hear) are then fed to a
``SwarmRecorder`` writing an .rrd file, in this process, repeatedly. The figure is the process
CPU time (all threads: the recorder's Python and Rerun's encoder and writer) from ``start()``
to ``close()`` divided by the frames logged, median of ``--repeat``; ``frames_per_s`` is its
inverse (the frame rate one core sustains). The sizes are interleaved (30, 300, 1000, 30, ...)
so drifting load hits each alike. Writes benchmarks/results/logger_scale.json.

    .venv/bin/python benchmarks/bench_logger_scale.py [--sizes 30,300,1000] [--seconds 34] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import tomllib
from pathlib import Path

from bench_io import finish, machine  # a sibling script

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "examples" / "swarm" / "swarm-n.toml"


def scenario(n: int, seconds: float):
    from fxswarm.core.scenario import parse

    data = tomllib.loads(CONFIG.read_text())
    data["swarm"]["count"] = n
    data["scenario"]["duration"] = seconds
    return parse(data, f"{CONFIG.name}+count={n}")


def states(sc) -> list:
    from fxswarm.launch.sim import Simulation
    from fxswarm.logger.replay import world_states

    sim = Simulation(sc, path="batch")
    sim.run()
    return list(world_states(sim.trajectory()))


def record_once(sc, world: list, out: Path, rate_hz: float) -> tuple[float, float, int]:
    """(CPU s, wall s, frames) of recording ``world`` to ``out``, from start() to close()."""
    from fxswarm.logger.recorder import RecorderOptions, SwarmRecorder
    from fxswarm.logger.sinks import Outputs, open_recording

    rec, _ = open_recording(Outputs(file=out), recording_id=out.stem)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    recorder = SwarmRecorder(sc, rec, RecorderOptions(rate_hz=rate_hz))
    recorder.start()
    for s in world:
        recorder.take("world/state", s, time.perf_counter())
    recorder.close()
    return time.process_time() - cpu0, time.perf_counter() - wall0, recorder.frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="30,300,1000")
    parser.add_argument("--seconds", type=float, default=34.0,
                        help="simulated seconds per run (dt 0.01); over 30 s the trail is at its full 30 s")
    parser.add_argument("--rate", type=float, default=25.0, help="frames per simulated second")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "benchmarks/results/logger_scale.json"))
    args = parser.parse_args()
    sizes = [int(x) for x in args.sizes.split(",")]
    at_start = machine()
    scenarios = {n: scenario(n, args.seconds) for n in sizes}
    world = {n: states(sc) for n, sc in scenarios.items()}
    cpu: dict[int, list[float]] = {n: [] for n in sizes}
    wall: dict[int, list[float]] = {n: [] for n in sizes}
    frames: dict[int, int] = {}
    sizes_mb: dict[int, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            for n in sizes:
                out = Path(tmp) / f"n{n}-{k}.rrd"
                c, w, frames[n] = record_once(scenarios[n], world[n], out, args.rate)
                cpu[n].append(c)
                wall[n].append(w)
                sizes_mb[n] = round(out.stat().st_size / 1e6, 2)
                out.unlink()
    by_n = {}
    for n in sizes:
        ms = 1e3 * statistics.median(cpu[n]) / frames[n]
        by_n[str(n)] = {"frames": frames[n], "cpu_ms_per_frame": round(ms, 3),
                        "cpu_ms_per_frame_all": [round(1e3 * c / frames[n], 3) for c in cpu[n]],
                        "wall_ms_per_frame": round(1e3 * statistics.median(wall[n]) / frames[n], 3),
                        "frames_per_cpu_s": round(1e3 / ms, 1), "rrd_mb": sizes_mb[n]}
    results = {
        "benchmark": "SwarmRecorder CPU per logged frame by swarm size (generated swarm, .rrd file sink)",
        "command": "benchmarks/bench_logger_scale.py " + " ".join(sys.argv[1:]),
        "machine": at_start,
        "config": str(CONFIG.relative_to(ROOT)), "seconds": args.seconds, "rate_hz": args.rate,
        "note": "process CPU (all threads) from start() to close() over frames logged, median of repeats; "
                "includes start() (static styles) and close() (the file flush)",
        "by_n": by_n,
    }
    return finish(args.out, results, by_n)


if __name__ == "__main__":
    sys.exit(main())
