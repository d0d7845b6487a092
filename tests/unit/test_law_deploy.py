"""A user's law carried by `fxswarm stack` and `fxswarm k8s` (issue 27), checked without a
cluster: the law module travels as a Swarm config / in the scenario's ConfigMap, mounted into
every role that loads the scenario, on its PYTHONPATH; the Kubernetes manifests validate against
the API schemas (strict). The compose path runs on the real engine: tests/docker/test_law_compose.py."""

from __future__ import annotations

import subprocess
from pathlib import Path

import kubernetes_validate
import pytest
import yaml

from docker_support import compose_command
from fxswarm.cli import main as fxswarm_main
from prerequisites import require

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "configs" / "examples" / "tether"
K8S_VERSION = "1.30.0"
ROLES = ("logger", "leader", "agent", "world")


def test_stack_hands_the_law_module_to_every_role_as_a_config(tmp_path):
    assert fxswarm_main(["stack", str(EXAMPLE / "tether.toml"), "--out", str(tmp_path)]) == 0
    doc = yaml.safe_load((tmp_path / "stack.yml").read_text())
    assert doc["configs"]["law"] == {"file": "./tether.py"}
    assert (tmp_path / "tether.py").read_text() == (EXAMPLE / "tether.py").read_text()
    for role in ROLES:
        service = doc["services"][role]
        assert {"source": "law", "target": "/app/law/tether.py", "mode": 0o444} in service["configs"], role
        assert service["environment"]["PYTHONPATH"] == "/app/law", role
    assert [c["source"] for c in doc["services"]["router"]["configs"]] == ["scenario"]


@pytest.mark.compose
def test_the_compose_tool_accepts_the_stack_file_carrying_the_law(tmp_path):
    """The compose tool's v3 schema knows configs: the stack file with the law passes `config -q`."""
    require("compose")
    tool = compose_command()
    assert fxswarm_main(["stack", str(EXAMPLE / "tether.toml"), "--out", str(tmp_path)]) == 0
    r = subprocess.run([*tool, "-f", str(tmp_path / "stack.yml"), "config", "-q"], capture_output=True, text=True,
                       cwd=tmp_path)
    assert r.returncode == 0, f"{' '.join(tool)}: {r.stderr}"


def test_stack_and_k8s_of_the_paper_carry_no_law(tmp_path):
    paper = REPO / "configs" / "paper-fast.toml"
    assert fxswarm_main(["stack", str(paper), "--out", str(tmp_path / "stack")]) == 0
    assert "law" not in yaml.safe_load((tmp_path / "stack" / "stack.yml").read_text())["configs"]
    assert fxswarm_main(["k8s", str(paper), "--out", str(tmp_path / "k8s")]) == 0
    assert "PYTHONPATH" not in (tmp_path / "k8s" / "agents.yaml").read_text()


def test_k8s_carries_the_law_module_in_the_scenario_configmap_and_validates(tmp_path):
    assert fxswarm_main(["k8s", str(EXAMPLE / "tether.toml"), "--out", str(tmp_path)]) == 0
    found = [o for f in sorted(tmp_path.glob("*.yaml")) for o in yaml.safe_load_all(f.read_text())]
    for obj in found:
        kubernetes_validate.validate(obj, K8S_VERSION, strict=True)
    (config,) = [o for o in found if o["kind"] == "ConfigMap"]
    assert config["data"]["tether.py"] == (EXAMPLE / "tether.py").read_text()
    pods = {o["metadata"]["labels"]["app.kubernetes.io/component"]: o["spec"]["template"]["spec"]
            for o in found if o["kind"] in ("Deployment", "StatefulSet", "Job")}
    for role in ROLES:
        (container,) = pods[role]["containers"]
        assert {"name": "scenario", "mountPath": "/app/law/tether.py", "subPath": "tether.py",
                "readOnly": True} in container["volumeMounts"], role
        assert {"name": "PYTHONPATH", "value": "/app/law"} in container["env"], role
    assert "PYTHONPATH" not in str(pods["router"])
