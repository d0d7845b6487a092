"""``fxswarm compose``: the generated compose file, the committed one, the one fault plan.

Pure: no process is started here. A compose tool reading the files and the
entry point script are in tests/integration/test_compose_tools.py, the engine
tests in tests/docker/test_docker_compose.py.
"""

from __future__ import annotations

import os

import pytest

from fxswarm.cli import main as fxswarm_main
from fxswarm.core.scenario import load
from fxswarm.launch import compose

from support import PAPER_FAST, REPO, ring_scenario


def test_the_committed_compose_file_is_what_the_generator_writes():
    """docker-compose.yml is generated: one idea, one place (regenerate it, never edit it)."""
    expected = compose.compose_file(load(PAPER_FAST), "configs/paper-fast.toml", REPO, REPO)
    assert (REPO / "docker-compose.yml").read_text() == expected, \
        "docker-compose.yml is stale: run `fxswarm compose configs/paper-fast.toml -o docker-compose.yml`"


def test_the_launchers_image_facts_are_the_images():
    """Compose, Swarm and Kubernetes files all take the user, the run folder and the working
    folder from compose.py; the images set them in the role Dockerfiles and install-role.sh."""
    install = (REPO / "docker" / "install-role.sh").read_text()
    assert f"groupadd --system --gid {compose.USER_ID} fxswarm" in install
    assert f"useradd --system --uid {compose.USER_ID} --gid fxswarm --home-dir /app" in install
    for _, dockerfile, _ in compose.IMAGES.values():
        text = (REPO / dockerfile).read_text()
        assert f'VOLUME ["{compose.IN_CONTAINER_RUNS}"]' in text, dockerfile
        assert f"WORKDIR {os.path.dirname(compose.IN_CONTAINER_SCENARIO)}" in text, dockerfile


def test_one_service_per_process_all_clients_of_the_router():
    doc = compose.services(load(PAPER_FAST), "./configs/paper-fast.toml", ".")["services"]
    assert list(doc) == ["router", "logger", "leader", *(f"agent-{i}" for i in range(1, 7)), "world"]
    # One image per role family, each built by the first service that runs it (the router runs
    # the world's); the others of the family start after that one, so none is pulled.
    builders = {s: doc[s]["build"]["dockerfile"] for s in doc if "build" in doc[s]}
    assert builders == {"router": "world/Dockerfile", "logger": "logger/Dockerfile",
                        "leader": "leader/Dockerfile", "agent-1": "agents/Dockerfile"}
    assert {doc[s]["image"] for s in doc} == {f"fxswarm-{r}:${{FXSWARM_TAG:-latest}}"
                                              for r in ("world", "logger", "leader", "agent")}
    for i in range(2, 7):
        assert "agent-1" in doc[f"agent-{i}"]["depends_on"]
    assert "router" in doc["world"]["depends_on"]
    assert all(doc[s]["user"] == "${FXSWARM_USER:-fxswarm}" for s in doc), "never root by default"
    # Every image declares the volume: a service without it mounted leaves an anonymous one at each `up`.
    assert all("./runs:/app/runs" in doc[s]["volumes"] for s in doc)
    for name, svc in doc.items():
        if name == "router":
            continue
        cmd = svc["command"]
        assert cmd[cmd.index("--mode") + 1] == "client"
        assert cmd[cmd.index("--connect") + 1] == "tcp/router:7447"
        assert cmd[cmd.index("--swarm") + 1] == "${FXSWARM_SWARM:-paper-fast}"
        assert cmd[cmd.index("--clock") + 1] == "${FXSWARM_CLOCK:-lockstep}"
        assert svc["environment"]["FXSWARM_FAULTS"] == "${FXSWARM_FAULTS:-}"  # only to be refused at `up`
        assert "./runs:/app/runs" in svc["volumes"]
    for i in range(1, 7):
        cmd = doc[f"agent-{i}"]["command"]
        assert cmd[cmd.index("--id") + 1] == str(i)
        assert doc[f"agent-{i}"]["healthcheck"]["test"] == ["CMD", "fxswarm", "health", "agent", str(i), "--quiet"]
    # The world starts the clock only once the logger records; it waits for the rest itself.
    assert doc["world"]["depends_on"]["logger"] == {"condition": "service_healthy"}


def test_any_number_of_robots(tmp_path):
    for n in (2, 3, 24):
        path = ring_scenario(tmp_path, n)
        doc = compose.services(load(path), str(path), ".")["services"]
        agents = [s for s in doc if s.startswith("agent-")]
        assert agents == [f"agent-{i}" for i in range(1, n + 1)]


def test_the_cli_writes_a_file_with_paths_relative_to_it(tmp_path, monkeypatch):
    path = ring_scenario(tmp_path, 3)
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


def test_every_service_receives_the_one_plan_resolved_when_the_file_is_written(tmp_path, monkeypatch):
    """`fxswarm compose` resolves [faults] + --fault + FXSWARM_FAULTS once, into FXSWARM_FAULT_PLAN."""
    import json

    from fxswarm.faults.plan import loads, resolve

    out = tmp_path / "compose.yml"
    monkeypatch.setenv("FXSWARM_FAULTS", "partition 5-8 isolate=3")
    assert fxswarm_main(["compose", str(PAPER_FAST), "-o", str(out), "--fault", "agent:*->agent:4 drop=0.2"]) == 0
    text = out.read_text()
    plans = {line.split(": ", 1)[1] for line in text.splitlines() if line.strip().startswith("FXSWARM_FAULT_PLAN:")}
    assert len(plans) == 1 and text.count("FXSWARM_FAULT_PLAN:") == 10  # router, logger, leader, 6 agents, world
    sc = load(PAPER_FAST)
    expected = resolve(sc, ["agent:*->agent:4 drop=0.2"], {"FXSWARM_FAULTS": "partition 5-8 isolate=3"})
    got = loads(json.loads(plans.pop()), sc, "compose.yml")
    assert got == expected and len(got.rules) == 1 and len(got.cuts) == 1
    monkeypatch.setenv("FXSWARM_FAULTS", "partition 10")  # a bad spec: no file, exit 2
    bad = tmp_path / "bad.yml"
    with pytest.raises(SystemExit) as exc:
        fxswarm_main(["compose", str(PAPER_FAST), "-o", str(bad)])
    assert exc.value.code == 2 and not bad.exists()
