"""``fxswarm stack`` and ``fxswarm k8s``: the files they write, checked without a cluster.

The Kubernetes manifests are validated offline against the Kubernetes API schemas
(``kubernetes-validate``, strict: unknown fields refused) for paper-fast and the 24-robot
``large`` scenario; the stack file is read by the compose tool (its v3 schema covers
``deploy``; prerequisite ``compose``). Real deployment on Swarm: tests/docker/test_stack.py.
"""

from __future__ import annotations

import base64
import json
import subprocess
from pathlib import Path

import kubernetes_validate
import pytest
import yaml

from fxswarm.cli import main as fxswarm_main

REPO = Path(__file__).resolve().parents[2]
CONFIGS = {"paper-fast": (REPO / "configs" / "paper-fast.toml", 6), "large": (REPO / "configs" / "large.toml", 24)}
K8S_VERSION = "1.30.0"


def objects(folder: Path) -> list[dict]:
    return [o for f in sorted(folder.glob("*.yaml")) if f.name != "kustomization.yaml"
            for o in yaml.safe_load_all(f.read_text())]


@pytest.mark.parametrize("name", list(CONFIGS))
def test_k8s_manifests_validate_against_the_kubernetes_schemas(tmp_path, name):
    path, robots = CONFIGS[name]
    assert fxswarm_main(["k8s", str(path), "--out", str(tmp_path), "--kustomize"]) == 0
    found = objects(tmp_path)
    for obj in found:
        kubernetes_validate.validate(obj, K8S_VERSION, strict=True)  # raises on any schema error
    kinds = {(o["kind"], o["metadata"]["name"]) for o in found}
    assert kinds == {("ConfigMap", f"{name}-scenario"), ("Deployment", f"{name}-router"),
                     ("Service", f"{name}-router"), ("Service", f"{name}-agent"),
                     ("StatefulSet", f"{name}-agent"), ("Deployment", f"{name}-leader"),
                     ("Deployment", f"{name}-logger"), ("Job", f"{name}-world")}
    (agents,) = [o for o in found if o["kind"] == "StatefulSet"]
    assert agents["spec"]["replicas"] == robots, "one scaled workload, not N copies"
    pod = agents["spec"]["template"]["spec"]
    assert pod["securityContext"]["runAsNonRoot"] and pod["securityContext"]["runAsUser"] == 10001
    (container,) = pod["containers"]
    assert {"name": "FXSWARM_ID_FROM_HOSTNAME", "value": "1"} in container["env"]
    assert "fxswarm health agent" in container["readinessProbe"]["exec"]["command"][-1]
    kustomization = yaml.safe_load((tmp_path / "kustomization.yaml").read_text())
    assert sorted(kustomization["resources"]) == sorted(f.name for f in tmp_path.glob("*.yaml")
                                                        if f.name != "kustomization.yaml")


def test_the_schema_check_is_real_a_broken_manifest_is_refused(tmp_path):
    assert fxswarm_main(["k8s", str(CONFIGS["paper-fast"][0]), "--out", str(tmp_path)]) == 0
    (agents,) = [o for o in objects(tmp_path) if o["kind"] == "StatefulSet"]
    agents["spec"]["replicas"] = "six"
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(agents, K8S_VERSION, strict=True)


def test_k8s_refuses_a_swarm_name_kubernetes_cannot_carry(tmp_path, capsys):
    with pytest.raises(SystemExit, match="expected lower-case letters"):
        fxswarm_main(["k8s", str(CONFIGS["paper-fast"][0]), "--out", str(tmp_path), "--swarm", "Paper_Fast"])
    assert not list(tmp_path.glob("*.yaml")), "nothing written"


def test_entrypoint_turns_the_pod_ordinal_and_the_task_slot_into_the_robot_id(tmp_path):
    fake = tmp_path / "fxswarm"
    fake.write_text('#!/bin/sh\nprintf "%s\\n" "$@"\n')
    fake.chmod(0o755)
    entry = REPO / "docker" / "entrypoint.sh"
    env = {"PATH": f"{tmp_path}:/usr/bin:/bin"}
    r = subprocess.run(["sh", str(entry), "agent", "s.toml"], capture_output=True, text=True,
                       env={**env, "FXSWARM_ID_FROM_HOSTNAME": "1", "HOSTNAME": "paper-fast-agent-0"})
    assert r.stdout.split() == ["agent", "s.toml", "--id", "1"]
    r = subprocess.run(["sh", str(entry), "agent", "s.toml"], capture_output=True, text=True,
                       env={**env, "FXSWARM_ID": "5"})
    assert r.stdout.split() == ["agent", "s.toml", "--id", "5"]
    r = subprocess.run(["sh", str(entry), "world", "s.toml"], capture_output=True, text=True,
                       env={**env, "FXSWARM_ID": "5"})
    assert r.stdout.split() == ["world", "s.toml"], "only agents take an id"


@pytest.mark.parametrize("name", list(CONFIGS))
def test_stack_file_one_scaled_agent_service_dnsrr_everywhere(tmp_path, name):
    path, robots = CONFIGS[name]
    assert fxswarm_main(["stack", str(path), "--out", str(tmp_path)]) == 0
    doc = yaml.safe_load((tmp_path / "stack.yml").read_text())
    services = doc["services"]
    assert sorted(services) == ["agent", "leader", "logger", "router", "world"]
    agent = services["agent"]
    assert agent["deploy"]["replicas"] == robots and agent["environment"]["FXSWARM_ID"] == "{{.Task.Slot}}"
    assert agent["deploy"]["restart_policy"]["condition"] == "on-failure", "a killed agent comes back"
    assert all(s["deploy"]["endpoint_mode"] == "dnsrr" for s in services.values())
    # Every image declares the volume: a task without it mounted leaves an anonymous one on its node.
    assert all({"type": "volume", "source": "runs", "target": "/app/runs"} in s["volumes"] for s in services.values())
    assert all("fxswarm health" in " ".join(s["healthcheck"]["test"]) or s["healthcheck"]["test"][1:4] ==
               ["fxswarm", "health", role] for role, s in services.items())
    # Swarm puts a task in its service's DNS only once healthy: the router must not ask `router`.
    assert services["router"]["healthcheck"]["test"][-2:] == ["--connect", "tcp/127.0.0.1:7447"]
    assert services["router"]["ports"][0]["mode"] == "host", "the ingress mesh does not go with dnsrr"
    world = services["world"]["command"]
    assert world[world.index("--wait-for") + 1] == "logger/0"
    # Restarted only on a crash before the end: a finished run exits 0 (--finished-ok, even flown
    # alone: test_world_degraded.py), and Swarm restarts on failure only.
    assert services["world"]["deploy"]["restart_policy"]["condition"] == "on-failure"
    assert "--finished-ok" in world
    assert (tmp_path / "scenario.toml").read_text() == path.read_text()


@pytest.mark.compose
@pytest.mark.parametrize("name", list(CONFIGS))
def test_stack_file_passes_the_compose_tools_schema(tmp_path, name):
    """The compose tool's v3 schema knows deploy, configs, long ports (prerequisite ``compose``:
    skips without one, fails so where FXSWARM_REQUIRE_DOCKER=1)."""
    from docker_support import compose_command
    from prerequisites import require

    require("compose")
    tool = compose_command()
    assert fxswarm_main(["stack", str(CONFIGS[name][0]), "--out", str(tmp_path)]) == 0
    r = subprocess.run([*tool, "-f", str(tmp_path / "stack.yml"), "config", "-q"], capture_output=True, text=True,
                       cwd=tmp_path)
    assert r.returncode == 0, f"{' '.join(tool)}: {r.stderr}"


def test_stack_refuses_robots_not_numbered_1_to_n(tmp_path):
    """A task slot is the robot id: a scenario whose ids are not 1..N cannot be one scaled service."""
    from fxswarm.core.scenario import load
    from fxswarm.launch.stack import check_ids

    sc = load(CONFIGS["paper-fast"][0])
    check_ids(sc)  # 1..6: fine
    shuffled = sc.__class__.__new__(sc.__class__)
    shuffled.__dict__.update(sc.__dict__)
    object.__setattr__(shuffled, "robots", tuple(reversed(sc.robots)))
    with pytest.raises(SystemExit, match=r"ids must be 1\.\.6 in order"):
        check_ids(shuffled)


# --- the resolved fault plan reaches every service, as compose passes it ----------------------

FAULTS = ["agent:2->agent:1 drop=0.3", "seed=7"]
FROM_ENV = "agent:3->world drop=0.1"


def expected_plan(path: Path) -> dict:
    from fxswarm.core.scenario import load
    from fxswarm.faults.plan import dumps, resolve

    sc = load(path)
    return json.loads(dumps(resolve(sc, FAULTS, {"FXSWARM_FAULTS": FROM_ENV}), sc))


def test_stack_hands_every_service_the_one_resolved_fault_plan(tmp_path, monkeypatch):
    path = CONFIGS["paper-fast"][0]
    monkeypatch.setenv("FXSWARM_FAULTS", FROM_ENV)  # read when the file is written, as compose does
    flags = [a for f in FAULTS for a in ("--fault", f)]
    assert fxswarm_main(["stack", str(path), "--out", str(tmp_path), *flags]) == 0
    services = yaml.safe_load((tmp_path / "stack.yml").read_text())["services"]
    want = expected_plan(path)
    assert [r["link"] for r in want["faults"]["links"]] == ["agent:2->agent:1", "agent:3->world"]
    for name, spec in services.items():
        env = spec["environment"]
        # `docker stack deploy` substitutes ${...}: the plan is written with $ doubled (none here)
        assert json.loads(env["FXSWARM_FAULT_PLAN"].replace("$$", "$")) == want, name
        # a FXSWARM_FAULTS set at deploy reaches the process, which refuses it beside a plan
        assert env["FXSWARM_FAULTS"] == "${FXSWARM_FAULTS:-}", name


def test_k8s_hands_every_container_the_one_resolved_fault_plan(tmp_path, monkeypatch):
    path = CONFIGS["paper-fast"][0]
    monkeypatch.setenv("FXSWARM_FAULTS", FROM_ENV)
    flags = [a for f in FAULTS for a in ("--fault", f)]
    assert fxswarm_main(["k8s", str(path), "--out", str(tmp_path), *flags]) == 0
    want = expected_plan(path)
    containers = [c for o in objects(tmp_path) if o["kind"] in ("Deployment", "StatefulSet", "Job")
                  for c in o["spec"]["template"]["spec"]["containers"]]
    assert len(containers) == 5
    for c in containers:
        env = {e["name"]: e["value"] for e in c["env"]}
        assert json.loads(env["FXSWARM_FAULT_PLAN"].replace("$$", "$")) == want, c["name"]
        assert env["FXSWARM_FAULTS"] == ""


def test_a_bad_fault_is_refused_when_the_files_are_written(tmp_path, capsys):
    for command in ("stack", "k8s"):
        with pytest.raises(SystemExit) as exc:
            fxswarm_main([command, str(CONFIGS["paper-fast"][0]), "--out", str(tmp_path / command),
                          "--fault", "agent:2->world drop=7"])
        assert exc.value.code == 2
        assert "drop: expected a probability" in capsys.readouterr().err
        assert not (tmp_path / command).exists(), "nothing written"


# --- secure mode: keys as Swarm secrets / Kubernetes Secrets, each process only its own --------

@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    folder = tmp_path_factory.mktemp("keys")
    assert fxswarm_main(["keys", str(folder), str(CONFIGS["paper-fast"][0])]) == 0
    return folder


def test_secure_stack_gives_each_service_its_own_key_as_swarm_secrets(tmp_path, keys):
    assert fxswarm_main(["stack", str(CONFIGS["paper-fast"][0]), "--out", str(tmp_path), "--secure", str(keys)]) == 0
    doc = yaml.safe_load((tmp_path / "stack.yml").read_text())
    services = doc["services"]
    for name, spec in services.items():
        assert "tls/router:7447" in spec["command"] or name == "router"
        assert not [a for a in spec["command"] if str(a).startswith("tcp/")], name
        mounted = {s["target"] for s in spec["secrets"]}
        if name == "agent":
            # one scaled service: every robot's pair, root's only; the entrypoint takes its own slot's
            assert mounted == {"ca.pem", *(f"agent-{i}.{e}" for i in range(1, 7) for e in ("pem", "key"))}
            assert {(s["uid"], s["mode"]) for s in spec["secrets"]} == {("0", 0o400)}
            assert spec["user"] == "0:0"
            env = spec["environment"]
            assert (env["FXSWARM_AGENT_KEYS"], env["FXSWARM_SECURE"], env["FXSWARM_RUN_AS"]) == \
                   ("/run/secrets", "/run/fxswarm-keys", "10001:10001")
            assert {"type": "tmpfs", "target": "/run/fxswarm-keys", "tmpfs": {"size": 1 << 20}} in spec["volumes"]
        else:
            assert mounted == {"ca.pem", f"{name}.pem", f"{name}.key"} | ({"access.json"} if name == "router" else set())
            assert {(s["uid"], s["gid"], s["mode"]) for s in spec["secrets"]} == {("10001", "10001", 0o400)}
            assert "user" not in spec, "the image's unprivileged user"
            assert spec["environment"]["FXSWARM_SECURE"] == "/run/secrets"
    assert services["router"]["command"][2] == "tls/0.0.0.0:7447"
    assert services["router"]["healthcheck"]["test"][-4:] == ["--connect", "tls/127.0.0.1:7447", "--timeout", "4"]
    # Secrets come from KEYS when deploying; ca.key (which makes identities) never.
    assert set(doc["secrets"]) == {p.name for p in keys.iterdir()} - {"ca.key", "observer.pem", "observer.key"}
    for name, source in doc["secrets"].items():
        assert (tmp_path / source["file"]).resolve() == (keys / name).resolve()


def test_secure_stack_and_k8s_refuse_a_missing_key_naming_it(tmp_path, keys, capsys):
    import shutil as _shutil

    broken = tmp_path / "keys"
    _shutil.copytree(keys, broken)
    (broken / "agent-4.key").unlink()
    for command in ("stack", "k8s"):
        with pytest.raises(SystemExit) as exc:
            fxswarm_main([command, str(CONFIGS["paper-fast"][0]), "--out", str(tmp_path / command),
                          "--secure", str(broken)])
        assert exc.value.code == 2
        assert "agent-4.key: missing" in capsys.readouterr().err
        assert not (tmp_path / command).exists(), "nothing written"


@pytest.mark.parametrize("name", list(CONFIGS))
def test_secure_k8s_manifests_validate_and_keep_each_key_in_its_own_pod(tmp_path_factory, name):
    path, robots = CONFIGS[name]
    folder = tmp_path_factory.mktemp(f"keys-{name}")
    assert fxswarm_main(["keys", str(folder), str(path)]) == 0
    out = tmp_path_factory.mktemp(f"k8s-{name}")
    assert fxswarm_main(["k8s", str(path), "--out", str(out), "--secure", str(folder), "--kustomize"]) == 0
    assert (out / "secrets.yaml").stat().st_mode & 0o077 == 0, "private keys: the user's only"
    found = objects(out)
    for obj in found:
        kubernetes_validate.validate(obj, K8S_VERSION, strict=True)
    secrets = {o["metadata"]["name"]: o for o in found if o["kind"] == "Secret"}
    agent_files = {"ca.pem", *(f"agent-{i}.{e}" for i in range(1, robots + 1) for e in ("pem", "key"))}
    assert {n: set(s["data"]) for n, s in secrets.items()} == {
        f"{name}-keys-router": {"ca.pem", "router.pem", "router.key", "access.json"},
        f"{name}-keys-world": {"ca.pem", "world.pem", "world.key"},
        f"{name}-keys-leader": {"ca.pem", "leader.pem", "leader.key"},
        f"{name}-keys-logger": {"ca.pem", "logger.pem", "logger.key"},
        f"{name}-keys-agent": agent_files}
    for s in secrets.values():
        for f, data in s["data"].items():
            assert base64.b64decode(data) == (folder / f).read_bytes()
    assert "secrets.yaml" in yaml.safe_load((out / "kustomization.yaml").read_text())["resources"]
    for obj in found:
        if obj["kind"] not in ("Deployment", "StatefulSet", "Job"):
            continue
        pod = obj["spec"]["template"]["spec"]
        (container,) = pod["containers"]
        role = container["name"]
        volumes = {v["name"]: v for v in pod["volumes"]}
        env = {e["name"]: e["value"] for e in container["env"]}
        assert env["FXSWARM_CONNECT"] == f"tls/{name}-router:7447"
        assert not [a for a in container["args"] if a.startswith("tcp/")]
        mounts = {m["mountPath"]: m["name"] for m in container["volumeMounts"]}
        if role != "agent":
            assert volumes[mounts["/run/secrets"]]["secret"]["secretName"] == f"{name}-keys-{role}"
            assert env["FXSWARM_SECURE"] == "/run/secrets"
            assert "initContainers" not in pod
            continue
        # The agent container sees only the copy of its own pair, in memory; the Secret with every
        # robot's pair is mounted into the init container alone.
        assert "/run/secrets" not in mounts and env["FXSWARM_SECURE"] == "/run/fxswarm-keys"
        assert volumes[mounts["/run/fxswarm-keys"]]["emptyDir"]["medium"] == "Memory"
        (init,) = pod["initContainers"]
        assert init["args"] == ["take-agent-key"] and init["image"] == container["image"]
        init_mounts = {m["mountPath"]: m["name"] for m in init["volumeMounts"]}
        assert volumes[init_mounts["/run/secrets"]]["secret"]["secretName"] == f"{name}-keys-agent"
        assert init_mounts["/run/fxswarm-keys"] == mounts["/run/fxswarm-keys"]


def test_entrypoint_takes_only_its_own_robots_key_from_the_folder_of_all(tmp_path, keys):
    """docker/entrypoint.sh take-agent-key (Kubernetes' init container; Swarm's agent tasks do the
    same before they start the agent): ca.pem and robot k's pair, nothing else, mode 0400."""
    entry = REPO / "docker" / "entrypoint.sh"
    dest = tmp_path / "mine"
    env = {"PATH": "/usr/bin:/bin", "FXSWARM_AGENT_KEYS": str(keys), "FXSWARM_SECURE": str(dest),
           "FXSWARM_ID_FROM_HOSTNAME": "1", "HOSTNAME": "paper-fast-agent-2"}
    r = subprocess.run(["sh", str(entry), "take-agent-key"], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in dest.iterdir()) == ["agent-3.key", "agent-3.pem", "ca.pem"]
    assert all(p.stat().st_mode & 0o777 == 0o400 for p in dest.iterdir())
    assert (dest / "agent-3.key").read_bytes() == (keys / "agent-3.key").read_bytes()
    r = subprocess.run(["sh", str(entry), "take-agent-key"], capture_output=True, text=True, env=env)
    assert r.returncode == 0, f"a second start (pod restarted) takes it again: {r.stderr}"
    r = subprocess.run(["sh", str(entry), "take-agent-key"], capture_output=True, text=True,
                       env={**env, "HOSTNAME": "paper-fast-agent-8"})
    assert r.returncode == 2 and "agent-9.pem: missing" in r.stderr
