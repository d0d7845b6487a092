"""``fxswarm stack --routers 2`` and ``fxswarm k8s --routers 2``: two routers meshed with each
other, kept apart on a cluster, and every process listing both (docs/routers.md)."""

from __future__ import annotations

from pathlib import Path

import kubernetes_validate
import pytest
import yaml

from fxswarm.cli import main as fxswarm_main

REPO = Path(__file__).resolve().parents[2]
PAPER_FAST = REPO / "configs" / "paper-fast.toml"
K8S_VERSION = "1.30.0"


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    folder = tmp_path_factory.mktemp("keys")
    assert fxswarm_main(["keys", str(folder), str(PAPER_FAST)]) == 0
    return folder


def connects(command: list[str]) -> list[str]:
    return [command[i + 1] for i, a in enumerate(command) if a == "--connect"]


def test_stack_two_router_services_meshed_apart_and_listed_by_every_process(tmp_path):
    assert fxswarm_main(["stack", str(PAPER_FAST), "--out", str(tmp_path), "--routers", "2"]) == 0
    services = yaml.safe_load((tmp_path / "stack.yml").read_text())["services"]
    r0, r1 = services["router"], services["router-1"]
    assert connects(r0["command"]) == ["tcp/router-1:7447"] and connects(r1["command"]) == ["tcp/router:7447"]
    assert r0["command"][r0["command"].index("--id") + 1] == "0" and r1["command"][r1["command"].index("--id") + 1] == "1"
    assert r0["deploy"]["restart_policy"]["condition"] == r1["deploy"]["restart_policy"]["condition"] == "any"
    assert r0["deploy"]["placement"]["constraints"] == ["node.labels.fxswarm.router != 1"]
    assert r1["deploy"]["placement"]["constraints"] == ["node.labels.fxswarm.router != 0"]
    assert r0["ports"][0]["published"] != r1["ports"][0]["published"]  # both on one node in a test
    assert r1["healthcheck"]["test"][3:5] == ["router", "1"]
    for role in ("world", "leader", "logger", "agent"):
        assert connects(services[role]["command"]) == ["tcp/router:7447", "tcp/router-1:7447"], role


def test_stack_one_router_by_default_as_before(tmp_path):
    assert fxswarm_main(["stack", str(PAPER_FAST), "--out", str(tmp_path)]) == 0
    services = yaml.safe_load((tmp_path / "stack.yml").read_text())["services"]
    assert [s for s in services if s.startswith("router")] == ["router"]
    assert "placement" not in services["router"]["deploy"]
    assert connects(services["agent"]["command"]) == ["tcp/router:7447"]


def test_secure_stack_gives_both_routers_the_router_keys(tmp_path, keys):
    assert fxswarm_main(["stack", str(PAPER_FAST), "--out", str(tmp_path / "d"), "--routers", "2",
                         "--secure", str(keys)]) == 0
    services = yaml.safe_load((tmp_path / "d" / "stack.yml").read_text())["services"]
    for name in ("router", "router-1"):
        assert sorted(s["source"] for s in services[name]["secrets"]) == ["access.json", "ca.pem", "router.key",
                                                                         "router.pem"]
        assert connects(services[name]["command"])[0].startswith("tls/")


def test_k8s_two_router_deployments_spread_over_nodes_and_listed_by_every_process(tmp_path):
    assert fxswarm_main(["k8s", str(PAPER_FAST), "--out", str(tmp_path), "--routers", "2"]) == 0
    found = [o for f in sorted(tmp_path.glob("*.yaml")) for o in yaml.safe_load_all(f.read_text())]
    for obj in found:
        kubernetes_validate.validate(obj, K8S_VERSION, strict=True)
    routers = {o["metadata"]["name"]: o for o in found if o["kind"] == "Deployment"
               and o["metadata"]["labels"]["app.kubernetes.io/component"] == "router"}
    assert sorted(routers) == ["paper-fast-router", "paper-fast-router-1"]
    services = {o["metadata"]["name"]: o for o in found if o["kind"] == "Service"}
    for i, name in enumerate(sorted(routers)):
        spec = routers[name]["spec"]["template"]["spec"]
        (spread,) = spec["topologySpreadConstraints"]
        assert spread["topologyKey"] == "kubernetes.io/hostname" and spread["whenUnsatisfiable"] == "DoNotSchedule"
        assert spread["labelSelector"]["matchLabels"]["app.kubernetes.io/component"] == "router"
        args = spec["containers"][0]["args"]
        assert args[args.index("--id") + 1] == str(i)
        other = "paper-fast-router-1" if i == 0 else "paper-fast-router"
        assert connects(args) == [f"tcp/{other}:7447"]
        # Each Service reaches its own router's pod only.
        assert services[name]["spec"]["selector"]["fxswarm/router"] == str(i)
        assert routers[name]["spec"]["template"]["metadata"]["labels"]["fxswarm/router"] == str(i)
    (agents,) = [o for o in found if o["kind"] == "StatefulSet"]
    assert connects(agents["spec"]["template"]["spec"]["containers"][0]["args"]) == [
        "tcp/paper-fast-router:7447", "tcp/paper-fast-router-1:7447"]
