"""``fxswarm compose``: the generated compose file, the committed one, the fault entry point.

No Docker engine needed here; the one test that asks a compose tool to read
the files skips when none is installed (the engine tests are in
test_docker_compose.py).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from fxswarm.cli import main as fxswarm_main
from fxswarm.core.scenario import load
from fxswarm.runtime import compose

REPO = Path(__file__).resolve().parents[1]
PAPER_FAST = REPO / "configs" / "paper-fast.toml"


def scenario_with(tmp_path: Path, robots: int) -> Path:
    """A copy of paper-fast with ``robots`` robots on a ring (offsets spread on a circle)."""
    import math

    text = PAPER_FAST.read_text()
    head = text[: text.index("[[robots]]")]
    tail = text[text.index("[[obstacles]]"):]
    rows = []
    for k in range(robots):
        a = 2 * math.pi * k / robots
        rows.append(f"[[robots]]\nposition = [{8 * math.cos(a):.3f}, {8 * math.sin(a):.3f}, 0.0]\n"
                    f"offset = [{3 * math.cos(a):.3f}, {3 * math.sin(a):.3f}, 0.0]\n")
    path = tmp_path / f"ring{robots}.toml"
    head = head.replace('name = "paper-fast"', f'name = "ring{robots}"')
    head = head.replace("pinned = [1, 4]", "pinned = [1]")
    path.write_text(head + "".join(rows) + "\n" + tail)
    return path


def test_the_committed_compose_file_is_what_the_generator_writes():
    """docker-compose.yml is generated: one idea, one place (regenerate it, never edit it)."""
    expected = compose.compose_file(load(PAPER_FAST), "configs/paper-fast.toml", REPO, REPO)
    assert (REPO / "docker-compose.yml").read_text() == expected, \
        "docker-compose.yml is stale: run `fxswarm compose configs/paper-fast.toml -o docker-compose.yml`"


def test_one_service_per_process_all_clients_of_the_router():
    doc = compose.services(load(PAPER_FAST), "./configs/paper-fast.toml", ".")["services"]
    assert list(doc) == ["router", "logger", "leader", *(f"agent-{i}" for i in range(1, 7)), "world"]
    assert "build" in doc["router"] and all("build" not in doc[s] for s in doc if s != "router")
    for name, svc in doc.items():
        if name == "router":
            continue
        cmd = svc["command"]
        assert cmd[cmd.index("--mode") + 1] == "client"
        assert cmd[cmd.index("--connect") + 1] == "tcp/router:7447"
        assert cmd[cmd.index("--swarm") + 1] == "${FXSWARM_SWARM:-paper-fast}"
        assert cmd[cmd.index("--clock") + 1] == "${FXSWARM_CLOCK:-lockstep}"
        assert svc["environment"]["FXSWARM_FAULTS"] == "${FXSWARM_FAULTS:-}"
        assert "./runs:/app/runs" in svc["volumes"]
    for i in range(1, 7):
        cmd = doc[f"agent-{i}"]["command"]
        assert cmd[cmd.index("--id") + 1] == str(i)
        assert doc[f"agent-{i}"]["healthcheck"]["test"] == ["CMD", "fxswarm", "health", "agent", str(i), "--quiet"]
    # The world starts the clock only once the logger records; it waits for the rest itself.
    assert doc["world"]["depends_on"]["logger"] == {"condition": "service_healthy"}


def test_any_number_of_robots(tmp_path):
    for n in (2, 3, 24):
        path = scenario_with(tmp_path, n)
        doc = compose.services(load(path), str(path), ".")["services"]
        agents = [s for s in doc if s.startswith("agent-")]
        assert agents == [f"agent-{i}" for i in range(1, n + 1)]


def test_the_cli_writes_a_file_with_paths_relative_to_it(tmp_path, monkeypatch):
    path = scenario_with(tmp_path, 3)
    out = tmp_path / "deploy" / "compose.yml"
    out.parent.mkdir()
    monkeypatch.chdir(REPO)
    assert fxswarm_main(["compose", str(path), "-o", str(out)]) == 0
    text = out.read_text()
    assert "agent-3:" in text and "agent-4:" not in text
    assert '"${FXSWARM_SCENARIO:-../ring3.toml}:/app/scenario.toml:ro"' in text
    assert f'context: "{os.path.relpath(REPO, out.parent)}"' in text


def test_render_quotes_every_string_and_refuses_other_types():
    assert compose.render({"a": {"b": "x: y", "c": 3, "d": ["p", "q"]}}) == \
        'a:\n  b: "x: y"\n  c: 3\n  d: ["p", "q"]\n'
    with pytest.raises(TypeError, match="expected str or int"):
        compose.render({"a": 1.5})
    with pytest.raises(TypeError):
        compose.render({"a": True})


def test_compose_tool_reads_the_files(tmp_path):
    """The compose tool on this machine accepts the committed file and a generated 24-robot one."""
    tool = (["docker", "compose"] if shutil.which("docker") and subprocess.run(
        ["docker", "compose", "version"], capture_output=True).returncode == 0 else
        ["docker-compose"] if shutil.which("docker-compose") else None)
    if tool is None:
        pytest.skip("no compose tool (`docker compose` or `docker-compose`) installed")
    r = subprocess.run([*tool, "-f", str(REPO / "docker-compose.yml"), "config", "-q"], capture_output=True,
                       text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    path = scenario_with(tmp_path, 24)
    out = tmp_path / "compose24.yml"
    (tmp_path / "Dockerfile").write_text("FROM scratch\n")  # a build context for `config` to find
    assert fxswarm_main(["compose", str(path), "-o", str(out), "--context", str(tmp_path)]) == 0
    r = subprocess.run([*tool, "-f", str(out), "config", "--services"], capture_output=True, text=True,
                       cwd=tmp_path, env={**os.environ, "FXSWARM_SWARM": "s24"})
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.split()) == 24 + 4


@pytest.mark.parametrize("faults, expected", [
    ("", []),
    ("agent:*->agent:4 loss=0.2", ["--fault", "agent:*->agent:4 loss=0.2"]),
    ("agent:*->agent:4 loss=0.2; ; partition 5-8 isolate=3;",
     ["--fault", "agent:*->agent:4 loss=0.2", "--fault", " partition 5-8 isolate=3"]),
])
def test_entrypoint_turns_fxswarm_faults_into_fault_options(tmp_path, faults, expected):
    """docker/entrypoint.sh: one --fault per ';'-separated spec, for role commands only."""
    fake = tmp_path / "fxswarm"
    fake.write_text('#!/bin/sh\nfor a; do printf "%s\\n" "$a"; done\n')
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{tmp_path}:{os.environ['PATH']}", "FXSWARM_FAULTS": faults}
    run = lambda *argv: subprocess.run(["sh", str(REPO / "docker" / "entrypoint.sh"), *argv],  # noqa: E731
                                       capture_output=True, text=True, env=env, check=True).stdout.splitlines()
    assert run("agent", "cfg.toml", "--id", "2") == ["agent", "cfg.toml", "--id", "2", *expected]
    assert run("router", "--swarm", "x") == ["router", "--swarm", "x"]  # not a role: no faults
