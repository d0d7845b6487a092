"""The secure swarm as a Docker Swarm stack (``fxswarm stack --secure``) runs to completion.

On a single-node Swarm (tests/docker/conftest.py ``swarm_mode``): ``fxswarm keys`` + ``fxswarm
stack --secure KEYS --fault ...``, deployed paper-fast (lock-step). Checked on the running
stack: the keys arrive as Swarm secrets (never in an image), each service holding only its own;
an agent task, which receives every robot's pair (one scaled service), runs ``fxswarm agent``
as uid 10001 with no capabilities, holding a copy of its own slot's pair only, and cannot read
the others. When the world's task completes, its run equals ``fxswarm sim`` with the same
``--fault`` flags bit for bit: the one resolved fault plan reached the world and every agent.
Then ``docker stack rm`` and nothing of the stack is left on the engine.
"""

from __future__ import annotations

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
from fxswarm.testing import scenario_with

pytestmark = [pytest.mark.docker, pytest.mark.stack, pytest.mark.timeout(1800)]

REPO = Path(__file__).resolve().parents[2]
# Lossy, late links between robots (applied in the agents' processes), a lossy link into the
# world, and a staleness limit and seed that only the plan carries.
FAULTS = ["agent:*->agent:* drop=0.3 delay=0.05", "agent:3->world drop=0.1", "staleness=0.1", "seed=11"]
USER = 10001


@pytest.fixture(scope="module")
def images(swarm_mode, role_images):
    return role_images


def fxswarm(*argv: str, timeout: float = 300) -> str:
    return sh(sys.executable, "-m", "fxswarm.cli", *argv, timeout=timeout)


def running_agent(stack: str) -> tuple[str, int] | None:
    """(container id, slot) of an agent task whose robot process is up (uid 10001), or None."""
    rows = sh("docker", "ps", "--filter", f"label=com.docker.swarm.service.name={stack}_agent",
              "--format", '{{.ID}} {{.Label "com.docker.swarm.task.name"}}').split("\n")
    for row in filter(str.strip, rows):
        cid, task = row.split()
        status = subprocess.run(["docker", "exec", cid, "cat", "/proc/1/status"], capture_output=True, text=True)
        if status.returncode == 0 and f"Uid:\t{USER}\t" in status.stdout:
            return cid, int(task.split(".")[1])
    return None


def world_state(stack: str) -> str:
    """The world task's current state, e.g. ``Running 3 seconds ago``, ``Complete ...``, ``Failed ...``."""
    return sh("docker", "service", "ps", f"{stack}_world", "--no-trunc", "--format", "{{.CurrentState}}").strip()


def service_log(stack: str, role: str, tail: str = "all") -> str:
    """A service's log, both streams (a process writes its own lines to stderr)."""
    return subprocess.run(["docker", "service", "logs", "--raw", "--tail", tail, f"{stack}_{role}"],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=60).stdout


def logs(stack: str) -> str:
    return "\n".join(f"--- {role} ---\n{service_log(stack, role, '30')}"
                     for role in ("router", "world", "agent", "leader", "logger"))


def test_secure_stack_runs_to_completion_with_keys_as_swarm_secrets_and_the_fault_plan(images):
    stack = f"fxsec{uuid.uuid4().hex[:8]}"
    folder = Path(tempfile.mkdtemp(prefix="fxswarm-secure-stack-"))
    # 40 s of paper-fast: long enough in lock-step to look into a running agent task.
    scenario = scenario_with(REPO / "configs" / "paper-fast.toml", folder, duration=40.0)
    keys = folder / "keys"
    flags = [a for f in FAULTS for a in ("--fault", f)]
    fxswarm("keys", str(keys), str(scenario))
    fxswarm("stack", str(scenario), "--out", str(folder / "deploy"), "--swarm", stack, "--secure", str(keys), *flags)
    fxswarm("sim", str(scenario), "--out", str(folder / "sim"), "--quiet", *flags)
    env = {**os.environ, "FXSWARM_TAG": TAG, "FXSWARM_ROUTER_PORT": str(free_port()), "FXSWARM_RUN": "run"}
    env.pop("FXSWARM_FAULTS", None)
    got = folder / "got"
    got.mkdir()
    try:
        sh("docker", "stack", "deploy", "-c", str(folder / "deploy" / "stack.yml"), stack, env=env, timeout=300)
        # A running agent task: its robot process is uid 10001, no capabilities, no new privileges.
        end = time.monotonic() + 600
        while (found := running_agent(stack)) is None:
            assert "Complete" not in world_state(stack), "the run ended before an agent task was looked at"
            if time.monotonic() > end:
                pytest.fail(f"no agent task running as uid {USER} after 600 s\n{logs(stack)}")
            time.sleep(0.5)
        cid, slot = found
        status = sh("docker", "exec", cid, "cat", "/proc/1/status")
        fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
        assert fields["Uid"].split() == [str(USER)] * 4 and fields["Gid"].split() == [str(USER)] * 4
        assert int(fields["CapEff"], 16) == 0 and int(fields["CapBnd"], 16) == 0 and fields["NoNewPrivs"].strip() == "1"
        assert "agent" in sh("docker", "exec", cid, "cat", "/proc/1/cmdline").split("\0")
        # Its own pair, copied from the secrets into a tmpfs; every robot's pair in /run/secrets,
        # which the robot's user cannot read.
        assert sorted(sh("docker", "exec", cid, "ls", "/run/fxswarm-keys").split()) == \
               sorted(["ca.pem", f"agent-{slot}.pem", f"agent-{slot}.key"])
        assert "tmpfs" in sh("docker", "exec", cid, "sh", "-c", "grep ' /run/fxswarm-keys ' /proc/mounts")
        other = 1 if slot != 1 else 2
        denied = subprocess.run(["docker", "exec", "--user", f"{USER}:{USER}", cid, "cat",
                                 f"/run/secrets/agent-{other}.key"], capture_output=True, text=True)
        assert denied.returncode != 0 and "Permission denied" in denied.stderr, denied
        # The world's task holds only its own pair (and the CA), as the images' user.
        (world,) = sh("docker", "ps", "-q", "--filter", f"label=com.docker.swarm.service.name={stack}_world").split()
        assert sorted(sh("docker", "exec", world, "ls", "/run/secrets").split()) == ["ca.pem", "world.key", "world.pem"]
        assert sh("docker", "exec", world, "id", "-u").strip() == str(USER)
        # The run goes to its end: the world's task completes (exit 0; a failure restarts it).
        end = time.monotonic() + 900
        while not world_state(stack).startswith("Complete"):
            if time.monotonic() > end:
                pytest.fail(f"the world's task did not complete in 900 s: {world_state(stack)}\n{logs(stack)}")
            time.sleep(2)
        router_log = service_log(stack, "router")
        sh("docker", "run", "--rm", "--user", "0", "-v", f"{stack}_runs:/r", "-v", f"{got}:/out", "--entrypoint", "sh",
           f"fxswarm-world:{TAG}", "-c", f"cp -r /r/run /out/ && chown -R {os.getuid()}:{os.getgid()} /out/run")
        secrets = sh("docker", "secret", "ls", "--filter", f"label=com.docker.stack.namespace={stack}",
                     "--format", "{{.Name}}").split()
    finally:
        remove_stack(stack)
    left = leftovers(stack)
    try:
        assert left == [], left
        assert "secure: mutual TLS on tls/0.0.0.0:7447" in router_log
        assert sorted(secrets) == sorted(f"{stack}_{p.name}" for p in keys.iterdir()
                                         if p.name not in ("ca.key", "observer.pem", "observer.key"))
        summary = json.loads((got / "run" / "summary.json").read_text())
        sim = json.loads((folder / "sim" / "summary.json").read_text())
        assert summary["complete"] and summary["ticks"] == sim["ticks"] == 4000, summary
        assert summary["faults"]["seed"] == 11
        link = "agent:3->world/command"
        assert summary["faults"]["links"][link] == sim["faults"]["links"][link]
        assert summary["faults"]["links"][link]["dropped"] > 0
        with np.load(got / "run" / "trajectory.npz") as run, np.load(folder / "sim" / "trajectory.npz") as expected:
            for key in ("p", "ph"):
                assert np.array_equal(run[key], expected[key]), f"{key}: the stack's run differs from fxswarm sim"
        assert (got / "run" / "recording.rrd").stat().st_size > 100_000, "the logger recorded under the rules"
    finally:
        shutil.rmtree(folder, ignore_errors=True)
