"""The role images, built once per test session for every docker test (tests/docker_support.py)."""

from __future__ import annotations

import os

import pytest

from docker_support import IMAGE, TAG, require_docker, run, sh
from support import REPO


@pytest.fixture(scope="session")
def role_images() -> str:
    """The role images (tag ``test``), built once per session on the registry-free local bases."""
    require_docker()
    if os.environ.get("FXSWARM_IMAGES_BUILT") != "1":  # =1: use the fxswarm-*:test images as they are
        run([str(REPO / "docker" / "build-images.sh")], 1800, "docker/build-images.sh",
             env={**os.environ, "FXSWARM_TAG": TAG})
    return IMAGE


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
    elif state != "active":
        pytest.skip(f"this engine's swarm state is {state!r}: neither active nor inactive")
    yield inited
    if inited:
        sh("docker", "swarm", "leave", "--force", timeout=120, check=False)
        if "docker_gwbridge" not in networks:  # swarm init makes it and leave keeps it: not ours to keep
            sh("docker", "network", "rm", "docker_gwbridge", check=False)
    assert set(sh("docker", "network", "ls", "--format", "{{.Name}}").split()) == networks, "networks as found"
    assert sh("docker", "info", "--format", "{{.Swarm.LocalNodeState}}").strip() == state, "swarm mode as found"
