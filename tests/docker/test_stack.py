"""The swarm as a Docker Swarm stack (``fxswarm stack``), observed with ``fxswarm attach``.

On a single-node Swarm (initialised for the test if this engine is not in swarm mode, and left
again afterwards; an active one is used as found), paper-fast (lock-step): deployed from
``fxswarm stack``, one agent task killed mid-run and replaced by Swarm in the same slot, the run
completed, ``fxswarm attach`` (outside the cluster, through the router's published port) writes
a summary within the bounds ``fxswarm run`` meets, equal to the world's own; then ``docker
stack rm`` and nothing of the stack is left on the engine.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from docker_support import TAG, leftovers, remove_stack, sh
from fxswarm.launch.launcher import free_port

pytestmark = [pytest.mark.docker, pytest.mark.stack, pytest.mark.timeout(1800)]

REPO = Path(__file__).resolve().parents[2]
SCENARIO = REPO / "configs" / "paper-fast.toml"


@pytest.fixture(scope="module")
def images(swarm_mode, role_images):
    return role_images


class Watch:
    """A Zenoh client of the stack's router: agents' liveliness, robot 3's commands, the world's time."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions

        self.bus = ZenohBus(swarm, ZenohOptions("client", (endpoint,), (), False, connect_timeout_ms=300_000))
        self.alive: set[str] = set()
        self.cmd3: list[float] = []  # simulation times of robot 3's commands
        self.world_t = -1.0
        self.bus.watch_alive("agent/*", lambda name, up: (self.alive.add if up else self.alive.discard)(name))
        self.bus.subscribe("agent/3/cmd", lambda _t, msg: self.cmd3.append(msg.t))
        self.bus.subscribe("world/state", self._state)

    def _state(self, _topic, msg) -> None:
        self.world_t = max(self.world_t, msg.t)

    def wait(self, what: str, done, timeout: float) -> None:
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() > end:
                pytest.fail(f"timed out after {timeout:g} s waiting for {what}")
            self.bus.poll(0.1)

    def close(self) -> None:
        self.bus.close()


def agent_task_container(stack: str, slot: int) -> str | None:
    rows = sh("docker", "ps", "--filter", f"label=com.docker.swarm.service.name={stack}_agent",
              "--format", '{{.ID}} {{.Label "com.docker.swarm.task.name"}}').split("\n")
    for row in rows:
        if row.strip() and row.split()[1].split(".")[1] == str(slot):
            return row.split()[0]
    return None


def finished_world_tasks(stack: str, timeout: float = 180.0) -> list[str]:
    """The world service's tasks' states (first word: Complete, Failed, Running, ...), once its
    first task has left Running (it serves its record a while after the run), plus the restart
    delay: a task Swarm restarts is a second task, made within the policy's 1 s delay."""
    def states() -> list[str]:
        out = sh("docker", "service", "ps", f"{stack}_world", "--format", "{{.CurrentState}}")
        return [line.split()[0] for line in out.splitlines() if line.strip()]

    end = time.monotonic() + timeout
    while any(s in ("Running", "Starting", "Preparing", "Pending", "Assigned", "Ready") for s in states()):
        assert time.monotonic() < end, f"the world still running {timeout:g} s after the run: {states()}"
        time.sleep(0.5)
    time.sleep(5.0)  # 5x the restart delay: a restart shows as a second task by then (nothing to wait on)
    return states()


def test_stack_runs_paper_fast_survives_a_killed_agent_and_attach_collects_the_run(images):
    stack = f"fxst{uuid.uuid4().hex[:8]}"
    folder = Path(tempfile.mkdtemp(prefix="fxswarm-stack-"))
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    # Lock-step runs at CPU speed and closes a dead robot's ticks at once: paper-fast's 40 s can be
    # over before Swarm has replaced the killed task. 100 s leaves room to rejoin and settle.
    text = SCENARIO.read_text()
    assert "duration = 40.0" in text
    scenario = folder / "paper-fast-100.toml"
    scenario.write_text(text.replace("duration = 40.0", "duration = 100.0"))
    sh(sys.executable, "-m", "fxswarm.cli", "stack", str(scenario), "--out", str(folder / "deploy"),
       "--swarm", stack, "--wait-for", "logger/0", "--wait-for", "observer/0")
    # FXSWARM_STACK_CLOCK=realtime flies it in real time (speed 1); lock-step (default) holds its
    # outcome on a loaded host, where real time on two cores shared by 28 containers does not.
    env = {**os.environ, "FXSWARM_TAG": TAG, "FXSWARM_ROUTER_PORT": str(port),
           "FXSWARM_CLOCK": os.environ.get("FXSWARM_STACK_CLOCK", "lockstep"), "FXSWARM_RUN": "run"}
    seen = folder / "seen"
    attach_log = (folder / "attach.log").open("w")
    attach = subprocess.Popen([sys.executable, "-m", "fxswarm.cli", "attach", endpoint, "--swarm", stack,
                               "--out", str(seen), "--timeout", "600"], stdout=attach_log, stderr=subprocess.STDOUT)
    watch = None
    started = time.monotonic()
    try:
        sh("docker", "stack", "deploy", "-c", str(folder / "deploy" / "stack.yml"), stack, env=env, timeout=300)
        watch = Watch(endpoint, stack)
        watch.wait("all six agents alive", lambda: len(watch.alive) == 6, 600)
        up_s = time.monotonic() - started
        watch.wait("simulation time 2 s", lambda: watch.world_t >= 2.0, 300)
        # Kill robot 3's task: Swarm must start a new task in slot 3, and robot 3 fly again.
        victim = agent_task_container(stack, 3)
        assert victim, "no running task in slot 3 of the agent service"
        sh("docker", "kill", victim)
        watch.wait("agent/3 gone", lambda: "agent/3" not in watch.alive, 60)
        heard = len(watch.cmd3)
        killed_t = watch.world_t
        watch.wait("agent/3 alive again (a new task in slot 3)", lambda: "agent/3" in watch.alive, 180)
        replacement = agent_task_container(stack, 3)
        assert replacement and replacement != victim
        watch.wait("a command from the new robot 3", lambda: len(watch.cmd3) > heard, 120)
        back_t = watch.cmd3[heard]
        code = attach.wait(600)
        world_tasks = finished_world_tasks(stack)
        said = (folder / "attach.log").read_text()
        print(f"stack up (all six agents alive) {up_s:.1f} s after deploy; agent 3 killed at t = {killed_t:.2f} s, "
              f"flying again at t = {back_t:.2f} s; attach said: {said.strip().splitlines()[-1]}")
        assert code == 0, said
        # The world's own run folder, from the stack's runs volume.
        own = json.loads(sh("docker", "run", "--rm", "--user", "0", "-v", f"{stack}_runs:/r", "--entrypoint", "cat",
                            f"fxswarm-world:{TAG}", "/r/run/summary.json"))
        own_npz = subprocess.run(["docker", "run", "--rm", "--user", "0", "-v", f"{stack}_runs:/r", "--entrypoint",
                                  "cat", f"fxswarm-world:{TAG}", "/r/run/trajectory.npz"],
                                 capture_output=True, timeout=120, check=True).stdout
    finally:
        if watch is not None:
            watch.close()
        if attach.poll() is None:
            attach.terminate()
            attach.wait(30)
        attach_log.close()
        remove_stack(stack)
    left = leftovers(stack)
    summary = json.loads((seen / "summary.json").read_text())
    recording_bytes = (seen / "recording.rrd").stat().st_size if (seen / "recording.rrd").exists() else 0
    with np.load(seen / "trajectory.npz") as traj:
        p_shape = traj["p"].shape
    # attach wrote the world's own record (world/record), not what the live stream brought: every tick.
    same_bytes = (seen / "trajectory.npz").read_bytes() == own_npz
    with np.load(seen / "trajectory.npz") as mine, np.load(io.BytesIO(own_npz)) as theirs:
        differ = sorted(k for k in set(mine.files) | set(theirs.files)
                        if k not in mine.files or k not in theirs.files or not np.array_equal(mine[k], theirs[k]))
    shutil.rmtree(folder, ignore_errors=True)
    assert left == [], left
    # Within the bounds `fxswarm run` meets on paper-fast, and the same figures the world computed.
    # states_missed counts what the live stream dropped under load (199 of 4000 once): the folder is whole anyway.
    assert summary["complete"] and summary["record"]["from"] == "world", summary.get("record")
    assert same_bytes and differ == [], differ
    assert summary["ticks"] == own["ticks"] == 10_000 and own["complete"]
    assert {k: v for k, v in summary.items() if k in own} == own  # the world's summary, whole
    assert summary["restarts"] == {"agent/3": [1, 1]}, summary["restarts"]
    # The world that finished its run exited 0 and Swarm (restart_policy on-failure) left it down:
    # the newest task is the one that completed, and no other did. (A world task that failed before
    # the end is restarted, as it should be: once, in a full CI run at load 8, ['Complete', 'Failed'].)
    assert world_tasks[0] == "Complete" and world_tasks.count("Complete") == 1, world_tasks
    assert summary["logger"] == {"seen": True, "died": False, "alive_at_end": summary["logger"]["alive_at_end"]}
    for key in ("ticks", "min_object_distance_m", "formation_error_final_m", "estimate_error_final_m"):
        assert summary[key] == own[key], key
    assert own["faults"]["degraded_ticks"].get("world_held_at_zero", {}).get("3", 0) > 0, "robot 3 was missed"
    # Only for an early kill: killed at 15, 20 or 25.16 s, `fxswarm sim` passes 1.76, 1.69 and 1.49 m
    # (docs/testing.md: the failed run's kill landed at 25.2 s). Say when it landed.
    assert summary["min_object_distance_m"] >= 1.8, (summary["min_object_distance_m"], killed_t, back_t)
    assert summary["formation_error_final_m"] <= 0.15
    assert summary["estimate_error_final_m"] <= 0.15
    assert recording_bytes > 100_000
    assert p_shape == (summary["ticks"], 6, 3)
