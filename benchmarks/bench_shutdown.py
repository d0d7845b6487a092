"""How fast the processes stop and refuse: the timings the integration tests used to assert.

    .venv/bin/python benchmarks/bench_shutdown.py [--rounds 3] [--out benchmarks/results/shutdown.json]

The tests (tests/integration/test_runtime_shutdown.py) assert the outcomes: every process
gone, the exit status, what was said. How long that took depends on the machine's load, so
it is measured here, in rounds that interleave the cases (A B C D, A B C D, ...), with
medians, beside a floor measured in the same rounds: the start-up of ``fxswarm --help``
(the interpreter and the CLI's imports, which every case below pays at least once).

* ``ctrl_c_stop_s``: ``fxswarm run`` (lock-step, 300 s scenario) up; SIGINT to the
  launcher; until it has exited (was asserted < 5 s).
* ``client_ctrl_c_s``: a leader waiting for a router nobody runs; SIGINT; until it exited
  (was asserted < 3 s).
* ``refuse_unwritable_out_s``: ``fxswarm sim`` with ``--out`` under a file; until it exited
  status 2 (was asserted < 30 s: refused up front, not after the run).
* ``router_port_taken_s``: ``fxswarm run --topology routed`` whose router's port is taken;
  until the launcher exited status 1 (was asserted by a 25 s timeout: its router's death is
  reported at once, not its own session's 30 s connect timeout).
* ``killed_agent_run_wall_s``: a lock-step 2 s paper-fast run whose agent 3 is SIGKILLed at
  0.5 s: the world's ``wall_s`` (was asserted < 60 s with a 1 s tick timeout: the world closes
  a dead robot's ticks at once, not at each deadline).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_io import machine, write_json  # a sibling script

ROOT = Path(__file__).resolve().parents[1]
PAPER_FAST = ROOT / "configs" / "paper-fast.toml"
#: The bounds the tests asserted before the timings moved here, s (reported, not enforced).
FORMER_BOUNDS_S = {"ctrl_c_stop_s": 5.0, "client_ctrl_c_s": 3.0, "refuse_unwritable_out_s": 30.0,
                   "router_port_taken_s": 25.0, "killed_agent_run_wall_s": 60.0}


def fxswarm(*args: object) -> list[str]:
    return [sys.executable, "-m", "fxswarm.cli", *map(str, args)]


def wait_for_line(proc: subprocess.Popen, needle: str, timeout: float = 120.0) -> None:
    """Read ``proc``'s stderr until a line holds ``needle``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            break
        if needle in line:
            return
    raise RuntimeError(f"never said {needle!r}")


def floor_s() -> float:
    t0 = time.perf_counter()
    subprocess.run(fxswarm("--help"), capture_output=True, check=True, timeout=120)
    return time.perf_counter() - t0


def ctrl_c_stop_s(tmp: Path) -> float:
    from fxswarm.testing import scenario_with

    config = scenario_with(PAPER_FAST, tmp, duration=300.0)
    proc = subprocess.Popen(fxswarm("run", config, "--out", tmp / "run", "--no-logger"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for_line(proc, "processes up")
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=120)
        took = time.perf_counter() - t0
        if proc.returncode != 130:
            raise RuntimeError(f"fxswarm run exited {proc.returncode} on SIGINT, not 130")
        return took
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def client_ctrl_c_s(tmp: Path) -> float:
    from fxswarm.launch.launcher import free_port

    port = free_port()  # nothing listens there
    proc = subprocess.Popen(fxswarm("leader", PAPER_FAST, "--swarm", "nobody", "--mode", "client", "--connect",
                                    f"tcp/127.0.0.1:{port}", "--out", tmp), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        wait_for_line(proc, "waiting for the router")
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
        return time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def refuse_unwritable_out_s(tmp: Path) -> float:
    (tmp / "a-file").write_text("")
    t0 = time.perf_counter()
    done = subprocess.run(fxswarm("sim", PAPER_FAST, "--out", tmp / "a-file" / "run"), capture_output=True,
                          timeout=300)
    took = time.perf_counter() - t0
    if done.returncode != 2:
        raise RuntimeError(f"fxswarm sim exited {done.returncode}, not 2")
    return took


def router_port_taken_s(tmp: Path) -> float:
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        t0 = time.perf_counter()
        done = subprocess.run(fxswarm("run", PAPER_FAST, "--out", tmp / "run", "--no-logger", "--port",
                                      taken.getsockname()[1], "--topology", "routed"), capture_output=True, timeout=300)
        took = time.perf_counter() - t0
    if done.returncode != 1:
        raise RuntimeError(f"fxswarm run exited {done.returncode}, not 1")
    return took


def killed_agent_run_wall_s(tmp: Path) -> float:
    from fxswarm.testing import SwarmUnderTest, scenario_with

    swarm = SwarmUnderTest(scenario_with(PAPER_FAST, tmp, duration=2.0), tmp / "run").start()
    try:
        swarm.wait_for_sim_time(0.5)
        os.kill(swarm.pid("agent-3"), signal.SIGKILL)
        return float(swarm.wait_done(timeout=600)["wall_s"])
    finally:
        swarm.stop()


CASES = {f.__name__: f for f in (ctrl_c_stop_s, client_ctrl_c_s, refuse_unwritable_out_s, router_port_taken_s,
                                 killed_agent_run_wall_s)}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "shutdown.json"))
    args = p.parse_args()
    runs: dict[str, list[float]] = {"floor_cli_start_s": [], **{name: [] for name in CASES}}
    loads = []
    for i in range(args.rounds):
        loads.append(round(os.getloadavg()[0], 2))
        runs["floor_cli_start_s"].append(floor_s())
        for name, case in CASES.items():
            with tempfile.TemporaryDirectory() as tmp:
                runs[name].append(case(Path(tmp)))
            print(f"round {i + 1}: {name} {runs[name][-1]:.2f} s", file=sys.stderr)
    medians = {name: round(statistics.median(v), 3) for name, v in runs.items()}
    result = {"machine": machine(), "load_avg_per_round": loads, "rounds": args.rounds,
              "runs_s": {k: [round(x, 3) for x in v] for k, v in runs.items()}, "median_s": medians,
              "former_test_bounds_s": FORMER_BOUNDS_S,
              "within_former_bounds": {k: medians[k] < b for k, b in FORMER_BOUNDS_S.items()}}
    write_json(args.out, result)
    print(json.dumps({"median_s": medians, "within_former_bounds": result["within_former_bounds"]}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
