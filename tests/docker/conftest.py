"""The role images, built once per test session for every docker test (tests/docker_support.py)."""

from __future__ import annotations

import os
import subprocess
import time
import warnings

import pytest

from docker_support import IMAGE, TAG, require_docker, run, sh
from prerequisites import unavailable
from support import REPO


@pytest.fixture(scope="session")
def role_images() -> str:
    """The role images (tag ``test``), built once per session on the registry-free local bases."""
    require_docker()
    if os.environ.get("FXSWARM_IMAGES_BUILT") != "1":  # =1: use the fxswarm-*:test images as they are
        run([str(REPO / "docker" / "build-images.sh")], 1800, "docker/build-images.sh",
             env={**os.environ, "FXSWARM_TAG": TAG})
    return IMAGE


@pytest.fixture(scope="module")
def stack_images(swarm_mode, role_images):
    """A swarm-mode engine and the role images, for a test that deploys a stack."""
    return role_images


@pytest.fixture(scope="session")
def swarm_mode():
    """A swarm-mode engine for the stack tests; yields whether it was initialised here (then it is
    left again at the end, and the docker_gwbridge network that init made is removed)."""
    require_docker()
    state = sh("docker", "info", "--format", "{{.Swarm.LocalNodeState}}").strip()
    networks = set(sh("docker", "network", "ls", "--format", "{{.Name}}").split())
    inited = False
    if state == "inactive":
        sh("docker", "swarm", "init", "--advertise-addr", "127.0.0.1", timeout=120)
        inited = True
    elif state != "active":  # pending, error, locked: no stack can deploy here
        unavailable("docker", f"this engine's swarm state is {state!r}: neither active nor inactive")
    yield inited
    stuck = None
    if inited:
        sh("docker", "swarm", "leave", "--force", timeout=120, check=False)
        if "docker_gwbridge" not in networks:  # swarm init makes it and leave keeps it: not ours to keep
            stuck = remove_gateway_bridge()
    left = set(sh("docker", "network", "ls", "--format", "{{.Name}}").split())
    if stuck is not None and left - networks == {"docker_gwbridge"}:
        # Docker 20.10 can keep a phantom endpoint on this bridge after a task container was killed
        # (moby/moby#37018: "has active endpoints", none listed); only a daemon restart clears it.
        # Everything else must be as found; this one is said, since no client call can remove it.
        warnings.warn(f"docker_gwbridge left behind: the engine refuses to remove it ({stuck}); "
                      "restarting dockerd clears it", stacklevel=1)
        left.discard("docker_gwbridge")
    assert left == networks, "networks as found"
    assert sh("docker", "info", "--format", "{{.Swarm.LocalNodeState}}").strip() == state, "swarm mode as found"


def remove_gateway_bridge(timeout: float = 30.0) -> str | None:
    """Remove the docker_gwbridge network that ``swarm init`` made; None once it is gone, else the
    engine's last refusal. Endpoints it lists are disconnected first; a refusal for active
    endpoints is waited on (the ingress sandbox can take a moment to go after ``swarm leave``)."""
    deadline = time.monotonic() + timeout
    while True:
        for ep in sh("docker", "network", "inspect", "docker_gwbridge", "--format",
                     "{{range .Containers}}{{.Name}} {{end}}", check=False).split():
            sh("docker", "network", "disconnect", "--force", "docker_gwbridge", ep, check=False)
        r = subprocess.run(["docker", "network", "rm", "docker_gwbridge"], capture_output=True, text=True, timeout=60)
        gone = "docker_gwbridge" not in sh("docker", "network", "ls", "--format", "{{.Name}}").split()
        if r.returncode == 0 or gone:
            return None
        if time.monotonic() > deadline:
            return r.stderr.strip()
        time.sleep(1)
