"""A run as compose starts it, without Docker: no launcher, a router and one process per role,
each handed the same resolved plan in FXSWARM_FAULT_PLAN. The world's summary.json then holds
every process's counters and the per-link fault counts, equal to `fxswarm sim`'s."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from fxswarm.core.scenario import load
from fxswarm.faults.plan import PLAN_ENV, dumps, resolve
from fxswarm.launch.launcher import free_port
from fxswarm.launch.sim import Simulation
from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import scenario_with

ROOT = Path(__file__).resolve().parents[2]
FLAGS = ["agent:*->agent:* drop=0.25 delay=0.03", "world->agent:2 kinds=sense drop=0.1"]


def test_every_process_takes_the_plan_from_the_variable_and_the_world_sums_their_counters(tmp_path):
    config = scenario_with(ROOT / "configs" / "paper-fast.toml", tmp_path, duration=2.0)
    sc = load(config)
    plan = resolve(sc, FLAGS)
    out = tmp_path / "run"
    port = free_port()
    swarm = f"compose-style-{os.getpid()}"
    common = ["--mode", "client", "--connect", f"tcp/127.0.0.1:{port}", "--swarm", swarm]
    env = {**os.environ, PLAN_ENV: dumps(plan, sc), "FXSWARM_FAULTS": ""}
    procs: list[subprocess.Popen] = []

    def start(name: str, *argv: str) -> subprocess.Popen:
        log = open(tmp_path / f"{name}.log", "wb")
        p = subprocess.Popen([sys.executable, "-m", "fxswarm.cli", *argv], stdout=log, stderr=log, env=env,
                             stdin=subprocess.DEVNULL)
        procs.append(p)
        return p

    try:
        start("router", "router", "--listen", f"tcp/127.0.0.1:{port}", "--swarm", swarm)
        start("leader", "leader", str(config), *common, "--out", str(out))
        for r in sc.robots:
            start(f"agent-{r.id}", "agent", str(config), "--id", str(r.id), *common, "--out", str(out))
        world = start("world", "world", str(config), *common, "--out", str(out), "--tick-timeout", "5")
        code = world.wait(timeout=300)
        logs = {p.name: p.read_text()[-1500:] for p in tmp_path.glob("*.log")}
        assert code == 0, logs
        for p in procs[1:]:
            assert p.wait(timeout=60) == 0, logs  # every role left by itself once the world ended the run
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()

    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["processes"]) == {"world-0", "leader-0", *(f"agent-{r.id}" for r in sc.robots)}
    sim = Simulation(sc, plan)
    expected = sim.run()
    assert np.array_equal(load_trajectory(out)["p"], sim.trajectory()["p"])  # the same plan, the same run
    assert summary["faults"]["links"] == expected["faults"]["links"]
    assert sum(c["dropped"] for c in summary["faults"]["links"].values()) > 0
    assert summary["faults"]["degraded_ticks"] == expected["faults"]["degraded_ticks"]
