"""Tools around the compose file, run as real processes: a compose tool reading the files
(prerequisite ``compose``: skipped where none is installed, failed so where
FXSWARM_REQUIRE_DOCKER=1; no Docker engine needed) and docker/entrypoint.sh."""

from __future__ import annotations

import os
import subprocess

import pytest

from fxswarm.cli import main as fxswarm_main

from docker_support import compose_command
from prerequisites import require
from support import REPO, ring_scenario


@pytest.mark.compose
def test_compose_tool_reads_the_files(tmp_path):
    """The compose tool on this machine accepts the committed file and a generated 24-robot one."""
    require("compose")
    tool = compose_command()
    r = subprocess.run([*tool, "-f", str(REPO / "docker-compose.yml"), "config", "-q"], capture_output=True,
                       text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    path = ring_scenario(tmp_path, 24)
    out = tmp_path / "compose24.yml"
    (tmp_path / "Dockerfile").write_text("FROM scratch\n")  # a build context for `config` to find
    assert fxswarm_main(["compose", str(path), "-o", str(out), "--context", str(tmp_path)]) == 0
    r = subprocess.run([*tool, "-f", str(out), "config", "--services"], capture_output=True, text=True,
                       cwd=tmp_path, env={**os.environ, "FXSWARM_SWARM": "s24"})
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.split()) == 24 + 4


@pytest.mark.parametrize("argv", [("agent", "cfg.toml", "--id", "2"), ("router", "--swarm", "x")])
def test_entrypoint_runs_fxswarm_with_its_arguments_unchanged(tmp_path, argv):
    """docker/entrypoint.sh adds nothing: the plan comes resolved in FXSWARM_FAULT_PLAN."""
    fake = tmp_path / "fxswarm"
    fake.write_text('#!/bin/sh\nfor a; do printf "%s\\n" "$a"; done\n')
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{tmp_path}:{os.environ['PATH']}", "FXSWARM_FAULTS": "partition 5-8 isolate=3"}
    r = subprocess.run(["sh", str(REPO / "docker" / "entrypoint.sh"), *argv], capture_output=True, text=True,
                       env=env, check=True)
    assert r.stdout.splitlines() == list(argv)
