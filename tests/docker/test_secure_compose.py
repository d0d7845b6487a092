"""The secure compose swarm on the real Docker engine runs to completion.

``fxswarm keys`` + ``fxswarm compose --secure``: every link mutual TLS, the
router enforcing the rules, each container holding only its own key (a compose
secret, never in the image) and running as uid 10001. The world starts only
once the logger's health check passed, so the health checks work under the
rules too. The role images of tests/docker/conftest.py (docker/build-images.sh,
registry-free). Everything made is removed at the end.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path

import pytest

from docker_support import TAG, compose_command, run as _run
from fxswarm.testing import scenario_with

pytestmark = [pytest.mark.docker, pytest.mark.timeout(1800)]

REPO = Path(__file__).resolve().parents[2]
USER = 10001  # the image's user (Dockerfile)


def test_secure_compose_swarm_runs_to_completion_as_non_root_with_keys_as_secrets(role_images):
    folder = Path(tempfile.mkdtemp(prefix="fxswarm-secure-compose-"))
    name = f"fxsec{uuid.uuid4().hex[:10]}"
    tool = compose_command()
    env = {**os.environ, "FXSWARM_TAG": TAG, "FXSWARM_SWARM": name, "FXSWARM_RUN": "run",
           "FXSWARM_ROUTER_PUBLISH": "127.0.0.1:"}  # an ephemeral host port
    try:
        scenario = scenario_with(REPO / "configs" / "paper-fast.toml", folder, duration=4.0)
        keys = folder / "keys"
        fx = [sys.executable, "-m", "fxswarm.cli"]
        _run([*fx, "keys", str(keys), str(scenario)], 120, "fxswarm keys")
        _run([*fx, "compose", str(scenario), "-o", str(folder / "docker-compose.yml"), "--secure", str(keys),
              "--context", str(REPO)], 120, "fxswarm compose --secure")
        (folder / "runs").mkdir()
        if os.geteuid() == 0:  # the containers' user must read its 0600 key and write ./runs
            for path in [keys, *keys.iterdir(), folder / "runs"]:
                os.chown(path, USER, USER)
        else:
            env.update(FXSWARM_UID=str(os.getuid()), FXSWARM_GID=str(os.getgid()))
        _run([*tool, "-p", name, "up", "--no-build", "--exit-code-from", "world"], 600, "compose up (secure)",
             env=env, cwd=folder)
        summary = json.loads((folder / "runs" / "run" / "summary.json").read_text())
        assert summary["complete"] and summary["ticks"] == 400, summary
        ids = _run([*tool, "-p", name, "ps", "-a", "-q"], 60, "compose ps", env=env, cwd=folder).split()
        assert len(ids) == 10  # router, logger, leader, six agents, world
        for info in json.loads(_run(["docker", "inspect", *ids], 60, "docker inspect")):
            assert info["State"]["ExitCode"] == 0 or info["Config"]["Labels"].get(
                "com.docker.compose.service") == "router", info["Name"]
            assert info["Config"]["User"] not in ("", "0", "root") and not info["Config"]["User"].startswith("0:")
            # The keys arrive as bind-mounted secrets, read-only, under /run/secrets.
            mounts = {m["Destination"]: m for m in info["Mounts"]}
            assert "/run/secrets/ca.pem" in mounts and not mounts["/run/secrets/ca.pem"]["RW"]
            service = info["Config"]["Labels"]["com.docker.compose.service"]
            assert f"/run/secrets/{service}.key" in mounts
            assert not [d for d in mounts if d.endswith(".key") and d != f"/run/secrets/{service}.key"]
        logs = _run([*tool, "-p", name, "logs", "--no-color", "router"], 60, "compose logs", env=env, cwd=folder)
        assert "secure: mutual TLS on tls/0.0.0.0:7447" in logs
        # No key is baked into any image: the four searches at once (each waits on its container's start).
        searches = {family: subprocess.Popen(
            ["docker", "run", "--rm", "--entrypoint", "sh", f"fxswarm-{family}:{TAG}", "-c",
             "find / -xdev \\( -name '*.key' -o -name 'ca.pem' \\) -not -path '/proc/*' 2>/dev/null; true"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for family in ("agent", "world", "leader", "logger")}
        for family, search in searches.items():
            found, err = search.communicate(timeout=120)
            assert search.returncode == 0, (family, err)
            assert found.strip() == "", (family, found)
    finally:
        subprocess.run([*tool, "-p", name, "down", "-v", "--remove-orphans", "--timeout", "5"], capture_output=True,
                       env=env, cwd=folder, timeout=180)
        if os.environ.get("FXSWARM_KEEP_COMPOSE_RUNS") != "1":
            shutil.rmtree(folder, ignore_errors=True)
