"""What the docker tests share: is an engine here, which compose tool, one command run with a clear failure."""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

# fxswarm-agent:test, fxswarm-world:test, ... (docker/build-images.sh). FXSWARM_TEST_TAG lets two
# checkouts test on one engine at once without one building over the other's images.
TAG = os.environ.get("FXSWARM_TEST_TAG", "test")
IMAGE = f"fxswarm-world:{TAG}"  # a role image with the router and health commands


def _answers(cmd: list[str], timeout: float = 30) -> tuple[bool, str]:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, str(exc)
    return r.returncode == 0, (r.stderr or r.stdout).strip()


def engine_problem() -> str | None:
    """Why the Docker tests cannot run here, or None if an engine and a compose tool answer."""
    if shutil.which("docker") is None:
        return "no `docker` client on PATH"
    ok, out = _answers(["docker", "info", "--format", "{{.ServerVersion}}"])
    if not ok:
        return f"no Docker engine answers (`docker info`: {out[-200:]})"
    if compose_command() is None:
        return "a Docker engine answers but no compose tool (`docker compose` or `docker-compose`) does"
    return None


@functools.cache  # asked by each compose test and its prerequisite check: `version` costs 0.35 s of CPU
def compose_command() -> list[str] | None:
    """The compose tool this machine has: the ``docker compose`` plugin, else ``docker-compose``."""
    if _answers(["docker", "compose", "version"])[0]:
        return ["docker", "compose"]
    if shutil.which("docker-compose") and _answers(["docker-compose", "version"])[0]:
        return ["docker-compose"]
    return None


def require_docker() -> None:
    """Return where an engine and a compose tool answer; else skip (fail: FXSWARM_REQUIRE_DOCKER=1)."""
    from prerequisites import require

    require("docker")


def run(cmd: list[str], timeout: float, what: str, env: dict | None = None, cwd: Path | None = None) -> str:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{what}: still running after {timeout:g} s: {' '.join(map(str, cmd))}")
    if r.returncode != 0:
        tail = "\n".join((r.stdout + r.stderr).strip().splitlines()[-30:])
        pytest.fail(f"{what} failed (exit {r.returncode}): {' '.join(map(str, cmd))}\n{tail}")
    return r.stdout


def sh(*cmd: str, timeout: float = 120, check: bool = True, env: dict | None = None) -> str:
    """Run ``cmd``; its stdout, or a test failure naming it (and its stderr) when it fails."""
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running after {timeout:g} s: {' '.join(cmd)}")
    if check and r.returncode != 0:
        pytest.fail(f"{' '.join(cmd)} failed ({r.returncode}): {(r.stderr or r.stdout)[-2000:]}")
    return r.stdout


def leftovers(stack: str) -> list[str]:
    """What of the Swarm stack ``stack`` is still on the engine (services, containers, networks,
    configs, secrets, its volumes)."""
    label = f"label=com.docker.stack.namespace={stack}"
    out = []
    for kind, cmd in (("service", ["docker", "service", "ls", "-q", "--filter", label]),
                      ("container", ["docker", "ps", "-aq", "--filter", label]),
                      ("network", ["docker", "network", "ls", "-q", "--filter", label]),
                      ("config", ["docker", "config", "ls", "-q", "--filter", label]),
                      ("secret", ["docker", "secret", "ls", "-q", "--filter", label]),
                      ("volume", ["docker", "volume", "ls", "-q", "--filter", f"name={stack}_"])):
        out += [f"{kind} {x}" for x in sh(*cmd).split()]
    return out


def remove_stack(stack: str, timeout: float = 180) -> None:
    """``docker stack rm``, wait (bounded) until its containers and networks are gone, then its volumes."""
    sh("docker", "stack", "rm", stack, check=False)
    end = time.monotonic() + timeout
    while time.monotonic() < end and [x for x in leftovers(stack) if not x.startswith("volume")]:
        time.sleep(1)
    for volume in sh("docker", "volume", "ls", "-q", "--filter", f"name={stack}_").split():
        sh("docker", "volume", "rm", volume, check=False)
