"""A user's law in containers (issue 27): `fxswarm compose` mounts the scenario's folder, with the
law module beside it, read-only on every role's PYTHONPATH; the compose swarm on the real Docker
engine flies that law, lock-step, bit for bit as `fxswarm sim` does. Without the mount the robots
could not import it: the same file with the mount taken out, a robot's container (agent-1, the
role that flies the law) refuses it (exit 2).
The role images of tests/docker/conftest.py; everything made is removed at the end."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import uuid
from pathlib import Path

import numpy as np
import pytest

from docker_support import TAG, compose_command, run as _run
from fxswarm.core.scenario import load
from fxswarm.launch.sim import Simulation
from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import dump_toml

pytestmark = [pytest.mark.docker, pytest.mark.timeout(1800)]

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "configs" / "examples" / "tether"


def test_compose_carries_the_users_law_to_every_container_and_flies_it_as_the_sim(role_images):
    folder = Path(tempfile.mkdtemp(prefix="fxswarm-law-compose-"))
    name = f"fxlaw{uuid.uuid4().hex[:10]}"
    tool = compose_command()
    env = {**os.environ, "FXSWARM_TAG": TAG, "FXSWARM_SWARM": f"law-{name}", "FXSWARM_RUN": "run",
           "FXSWARM_ROUTER_PUBLISH": "127.0.0.1:"}  # an ephemeral host port
    try:
        scenario_dir = folder / "scenario"
        scenario_dir.mkdir()
        shutil.copy(EXAMPLE / "tether.py", scenario_dir / "tether.py")
        data = tomllib.loads((EXAMPLE / "tether.toml").read_text())
        data["scenario"]["duration"] = 2.0
        scenario = scenario_dir / "tether.toml"
        scenario.write_text(dump_toml(data))
        compose = folder / "docker-compose.yml"
        _run([sys.executable, "-m", "fxswarm.cli", "compose", str(scenario), "-o", str(compose),
              "--context", str(REPO)], 120, "fxswarm compose")
        text = compose.read_text()
        assert text.count('"./scenario:/app/law:ro"') == 9  # logger, leader, six agents, world
        assert text.count('PYTHONPATH: "/app/law"') == 9
        (folder / "runs").mkdir()
        (folder / "runs").chmod(0o777)  # the containers run as uid 10001, not as this user
        _run([*tool, "-p", name, "up", "--no-build", "--exit-code-from", "world"], 900, "compose up (law)",
             env=env, cwd=folder)
        out = folder / "runs" / "run"
        summary = json.loads((out / "summary.json").read_text())
        assert summary["complete"] and summary["ticks"] == 200 and summary["missed_ticks"] == 0, summary
        assert summary["law"] == {"name": "tether:Tether", "errors": {}}
        sim = Simulation(load(scenario))
        sim.run()
        expected, got = sim.trajectory(), load_trajectory(out)
        for key in expected:
            assert np.array_equal(got[key], expected[key]), key
        subprocess.run([*tool, "-p", name, "down", "-v", "--remove-orphans", "--timeout", "5"], capture_output=True,
                       env=env, cwd=folder, timeout=180)

        # The mount is what carries the law: without it an agent cannot import it and says so.
        bare = re.sub(r',?\s*"\./scenario:/app/law:ro"', "", text)
        assert "/app/law:ro" not in bare
        compose.write_text(bare)
        proc = subprocess.run([*tool, "-p", name, "run", "--rm", "--no-deps", "agent-1"], capture_output=True,
                              text=True, env=env, cwd=folder, timeout=300)
        assert proc.returncode == 2, proc.stdout + proc.stderr
        assert "controller.law: cannot import 'tether'" in proc.stdout + proc.stderr
    finally:
        subprocess.run([*tool, "-p", name, "down", "-v", "--remove-orphans", "--timeout", "5"], capture_output=True,
                       env=env, cwd=folder, timeout=180)
        if os.geteuid() != 0 and (folder / "runs").exists():  # files the containers (uid 10001) wrote
            subprocess.run(["docker", "run", "--rm", "--user", "0", "--entrypoint", "chown", "-v",
                            f"{folder}/runs:/r", role_images, "-R", f"{os.getuid()}:{os.getgid()}", "/r"],
                           capture_output=True)
        if os.environ.get("FXSWARM_KEEP_COMPOSE_RUNS") != "1":
            shutil.rmtree(folder, ignore_errors=True)
