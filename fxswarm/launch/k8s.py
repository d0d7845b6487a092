"""``fxswarm k8s CONFIG --out DIR``: Kubernetes manifests that run a scenario on a cluster.

Plain YAML, one file per workload, for ``kubectl apply -f DIR``; with
``--kustomize`` also a ``kustomization.yaml`` listing them, for ``kubectl
apply -k DIR`` (set a namespace or an image registry there; ``-f`` would
then refuse that file, which is no Kubernetes object). Every name starts with the swarm
name, so two swarms share a namespace (and their key expressions a router
mesh) without cross-talk:

* ``<swarm>-scenario`` ConfigMap: the scenario file, mounted into every pod;
* ``<swarm>-router`` Deployment + Service (port 7447): the Zenoh router all
  processes are clients of; reach it from outside with ``kubectl
  port-forward svc/<swarm>-router 7447`` and ``fxswarm attach``. ``--routers 2``:
  also ``<swarm>-router-1``, meshed with it, the two pods spread over nodes
  (``topologySpreadConstraints`` on the host name); every process lists both;
* ``<swarm>-agent`` StatefulSet with the robot count as replicas (+ its
  headless Service): pod ordinal k is robot k + 1 (the entrypoint reads it
  from the pod name); ``podManagementPolicy: Parallel`` starts them all at
  once; a killed agent pod is recreated under the same name and rejoins;
* ``<swarm>-leader`` and ``<swarm>-logger`` Deployments;
* ``<swarm>-world`` Job: the run itself; it completes when the run ends
  (``restartPolicy: OnFailure``: a crashed world runs again). It waits on
  liveliness for the leader, the agents and the logger (no start order).

Probes are ``fxswarm health ROLE ID`` (the process's liveliness token, asked
of the router). Pods run as uid 10001, no
privilege escalation, no capabilities; runs go to an ``emptyDir`` at /app/runs (collect them
with ``fxswarm attach``).

Faults: the scenario's ``[faults]``, ``--fault`` flags and ``FXSWARM_FAULTS`` (read when the
manifests are written) resolve into one plan, every container's ``FXSWARM_FAULT_PLAN``, as
``fxswarm compose`` does.

Secure mode (``--secure KEYS``, docs/security.md): every link is ``tls/``, and ``secrets.yaml``
(mode 0600: it holds private keys) has one Secret per process family: ``<swarm>-keys-router``
(``ca.pem``, the router's pair, ``access.json``), ``-world``, ``-leader``, ``-logger``, each
mounted read-only at /run/secrets in its own pod only, and ``<swarm>-keys-agent`` with
``ca.pem`` and every robot's pair (a StatefulSet's pods share one template). That one is
mounted only into the agent pod's init container, which copies ``ca.pem`` and its own
ordinal's pair into an in-memory ``emptyDir`` (docker/entrypoint.sh ``take-agent-key``); the
agent container mounts only that copy.
"""

from __future__ import annotations

import argparse
import base64
import copy
import os
import re
import sys
from pathlib import Path

from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FAULTS_ENV, PLAN_ENV, FaultPlan, dumps, plan_of
from fxswarm.launch.compose import (IN_CONTAINER_LAW, IN_CONTAINER_RUNS, IN_CONTAINER_SCENARIO, ROUTER_PORT,
                                    SECRETS_DIR, USER_ID, add_fault_and_secure_arguments, image, law_module)
from fxswarm.launch.stack import AGENT_KEYS_DIR, WAIT_TIMEOUT_S, check_ids, checked_keys, dump_yaml, header
from fxswarm.runtime.numbers import swarm_name


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write the manifests into")
    p.add_argument("--swarm", type=swarm_name, default=None,
                   help="swarm name: key-expression prefix and name prefix of every object (default: the "
                        "scenario's name; letters, digits and '-')")
    p.add_argument("--tag", default="latest", help="tag of the fxswarm-<role> images (default latest)")
    p.add_argument("--clock", choices=("lockstep", "realtime"), default="lockstep",
                   help="the world's clock: lockstep (bit-identical to `fxswarm sim`) or realtime (default lockstep)")
    p.add_argument("--wait-for", action="append", default=None, metavar="ROLE/ID",
                   help="what the world waits for besides the leader and agents (default logger/0)")
    p.add_argument("--routers", type=int, choices=(1, 2, 3), default=1,
                   help="router Deployments (each with its Service), meshed with each other and spread over "
                        "nodes; every process lists them all and fails over (default 1)")
    p.add_argument("--kustomize", action="store_true",
                   help="also write kustomization.yaml (then apply with -k DIR, not -f DIR)")
    add_fault_and_secure_arguments(p, "container", "the keys go into Kubernetes Secrets in DIR/secrets.yaml")


def dns_name(swarm: str) -> str:
    """``swarm`` if it is a valid DNS-1123 label prefix (names are ``<swarm>-<role>``), else exit 2."""
    if not re.fullmatch(r"[a-z0-9]([-a-z0-9]{0,40}[a-z0-9])?", swarm):
        raise SystemExit(f"fxswarm k8s: swarm name {swarm!r}: expected lower-case letters, digits and '-' "
                         "(at most 42, starting and ending with a letter or digit): Kubernetes names carry it")
    return swarm


def manifests(sc: Scenario, scenario_text: str, swarm: str, tag: str = "latest", clock: str = "lockstep",
              wait_for: list[str] | None = None, plan: FaultPlan | None = None,
              keys: Path | None = None, law: tuple[str, str] | None = None, routers: int = 1) -> dict[str, list[dict]]:
    """File name -> the Kubernetes objects it holds.

    ``plan``: the run's resolved fault plan (default: the scenario's ``[faults]``); ``keys``:
    secure mode's keys folder (checked), whose files go into ``secrets.yaml``, or None;
    ``law``: ``(module, source text)`` of a law module beside the scenario
    (:func:`fxswarm.launch.compose.law_module`), carried in the scenario's ConfigMap onto
    every role's PYTHONPATH, or None.
    """
    m = _Objects(sc, swarm, tag, clock, plan, keys, law, routers)
    agent_pod = m.pod("agent", m.command("agent"), ident=AGENT_ID,
                      extra_env=[{"name": "FXSWARM_ID_FROM_HOSTNAME", "value": "1"}])
    world_args = m.command("world", ["--tick-timeout", "5", "--wait-timeout", str(WAIT_TIMEOUT_S)])
    for name in wait_for if wait_for is not None else ["logger/0"]:
        world_args += ["--wait-for", name]
    files = {
        "scenario.yaml": [{"apiVersion": "v1", "kind": "ConfigMap", "metadata": m.meta("scenario", "scenario"),
                           "data": {"scenario.toml": scenario_text,
                                    **({f"{law[0]}.py": law[1]} if law is not None else {})}}],
        "router.yaml": m.routers(),
        "agents.yaml": [
            m.service("agent", "agent", headless=True),
            {"apiVersion": "apps/v1", "kind": "StatefulSet", "metadata": m.meta("agent", "agent"),
             "spec": {"serviceName": f"{swarm}-agent", "replicas": sc.n, "podManagementPolicy": "Parallel",
                      "selector": {"matchLabels": {**m.labels, "app.kubernetes.io/component": "agent"}},
                      "template": agent_pod}},
        ],
        "leader.yaml": [m.deployment("leader", m.command("leader"))],
        "logger.yaml": [m.deployment("logger", m.command("logger", ["--rerun", "file"]))],
        "world.yaml": [{"apiVersion": "batch/v1", "kind": "Job", "metadata": m.meta("world", "world"),
                        "spec": {"backoffLimit": 3, "template": m.pod("world", world_args, restart="OnFailure")}}],
    }
    if keys is not None:
        files["secrets.yaml"] = [secret_object(f"{swarm}-keys-{role}", m.meta(f"keys-{role}", role), keys, names)
                                 for role, names in key_files(sc).items()]
    return files


# Ordinal k (the pod name's suffix) is robot k + 1: the entrypoint and the probes compute it.
AGENT_ID = '$(( ${HOSTNAME##*-} + 1 ))'


class _Objects:
    """The parts every manifest is made of, for one swarm (see :func:`manifests`)."""

    def __init__(self, sc: Scenario, swarm: str, tag: str, clock: str, plan: FaultPlan | None,
                 keys: Path | None, law: tuple[str, str] | None, routers: int) -> None:
        self.swarm, self.tag, self.clock, self.keys, self.law, self.n_routers = swarm, tag, clock, keys, law, routers
        self.scheme = "tls" if keys is not None else "tcp"
        self.router_names = ["router" if i == 0 else f"router-{i}" for i in range(routers)]
        self.endpoints = [f"{self.scheme}/{swarm}-{name}:{ROUTER_PORT}" for name in self.router_names]
        self.labels = {"app.kubernetes.io/part-of": "fxswarm", "fxswarm/swarm": swarm}
        self.run = f"{IN_CONTAINER_RUNS}/{sc.name}"
        # Kubernetes expands $(NAME) in env values and reduces $$ to $: a literal $ is written $$.
        plan_json = dumps(plan if plan is not None else plan_of(sc), sc).replace("$", "$$")
        self.env = [{"name": "FXSWARM_SWARM", "value": swarm}, {"name": "FXSWARM_CONNECT", "value": self.endpoints[0]},
                    {"name": PLAN_ENV, "value": plan_json}, {"name": FAULTS_ENV, "value": ""}]

    def meta(self, name: str, role: str) -> dict:
        return {"name": f"{self.swarm}-{name}", "labels": {**self.labels, "app.kubernetes.io/component": role}}

    def probe(self, role: str, ident: str) -> dict:
        check = f"fxswarm health {role} {ident} --quiet"
        if role == "router":  # its Service routes to it only once it is ready: it asks itself
            check += f" --connect {self.scheme}/127.0.0.1:{ROUTER_PORT}"
        else:  # a router restarting must not fail every other pod's probes meanwhile
            check += " --router-down-ok"
        if self.keys is not None:  # a TLS handshake on a loaded node can outlast health's default 2 s
            check += " --timeout 4"
        return {"exec": {"command": ["sh", "-c", check]}, "initialDelaySeconds": 20, "periodSeconds": 10,
                "timeoutSeconds": 15, "failureThreshold": 6}

    def container(self, role: str, args: list[str], ident: str, extra_env: list[dict] | None) -> dict:
        return {
            "name": role,
            "image": image(role, self.tag),
            "imagePullPolicy": "IfNotPresent",
            "args": args,
            "env": self.env + (extra_env or []),
            # A slow start (imports, the router not up yet) is not a failure: up to 300 s of it.
            "startupProbe": {**self.probe(role, ident), "initialDelaySeconds": 5, "failureThreshold": 30},
            "readinessProbe": self.probe(role, ident),
            "livenessProbe": self.probe(role, ident),
            "resources": {"requests": {"cpu": "50m", "memory": "64Mi"}},
            "securityContext": {"allowPrivilegeEscalation": False,
                                "capabilities": {"drop": ["ALL"]}},
            "volumeMounts": [{"name": "scenario", "mountPath": IN_CONTAINER_SCENARIO, "subPath": "scenario.toml",
                              "readOnly": True},
                             {"name": "runs", "mountPath": IN_CONTAINER_RUNS},
                             {"name": "tmp", "mountPath": "/tmp"}],
        }

    def pod(self, role: str, args: list[str], ident: str = "0", extra_env: list[dict] | None = None,
            restart: str | None = None) -> dict:
        container = self.container(role, args, ident, extra_env)
        law = self.law
        if role == "router":
            container["ports"] = [{"name": "zenoh", "containerPort": ROUTER_PORT, "protocol": "TCP"}]
        elif law is not None:  # every role loads the scenario, and so imports its law
            container["volumeMounts"].insert(1, {"name": "scenario", "mountPath": f"{IN_CONTAINER_LAW}/{law[0]}.py",
                                                 "subPath": f"{law[0]}.py", "readOnly": True})
            container["env"] = container["env"] + [{"name": "PYTHONPATH", "value": IN_CONTAINER_LAW}]
        spec = {
            "securityContext": {"runAsNonRoot": True, "runAsUser": USER_ID, "runAsGroup": USER_ID, "fsGroup": USER_ID},
            "containers": [container],
            "volumes": [{"name": "scenario", "configMap": {"name": f"{self.swarm}-scenario"}},
                        {"name": "runs", "emptyDir": {}}, {"name": "tmp", "emptyDir": {}}],
        }
        if self.keys is not None:
            self.secure_pod(spec, container, role)
        if restart:
            spec["restartPolicy"] = restart
        return {"metadata": {"labels": {**self.labels, "app.kubernetes.io/component": role}}, "spec": spec}

    def secure_pod(self, spec: dict, container: dict, role: str) -> None:
        """Mount the role's Secret at /run/secrets; the agent's through an init container."""
        secret = {"name": "keys-all" if role == "agent" else "keys",
                  "secret": {"secretName": f"{self.swarm}-keys-{role}", "defaultMode": 0o440}}
        spec["volumes"].append(secret)
        if role != "agent":
            container["env"] = container["env"] + [{"name": "FXSWARM_SECURE", "value": SECRETS_DIR}]
            container["volumeMounts"].append({"name": "keys", "mountPath": SECRETS_DIR, "readOnly": True})
            return
        spec["volumes"].append({"name": "keys", "emptyDir": {"medium": "Memory", "sizeLimit": "1Mi"}})
        own = {"name": "keys", "mountPath": AGENT_KEYS_DIR}
        spec["initContainers"] = [{
            "name": "take-agent-key", "image": container["image"], "imagePullPolicy": "IfNotPresent",
            "args": ["take-agent-key"],
            "env": [{"name": "FXSWARM_ID_FROM_HOSTNAME", "value": "1"},
                    {"name": "FXSWARM_AGENT_KEYS", "value": SECRETS_DIR},
                    {"name": "FXSWARM_SECURE", "value": AGENT_KEYS_DIR}],
            "resources": copy.deepcopy(container["resources"]),
            "securityContext": copy.deepcopy(container["securityContext"]),
            "volumeMounts": [{"name": "keys-all", "mountPath": SECRETS_DIR, "readOnly": True}, own]}]
        container["env"] = container["env"] + [{"name": "FXSWARM_SECURE", "value": AGENT_KEYS_DIR}]
        container["volumeMounts"].append({**own, "readOnly": True})

    def command(self, role: str, extra: list[str] | None = None) -> list[str]:
        every = [a for e in self.endpoints for a in ("--connect", e)]  # several: the next when one is lost
        return [role, IN_CONTAINER_SCENARIO, "--mode", "client", *every, "--no-multicast",
                "--swarm", self.swarm, "--clock", self.clock, "--out", self.run, *(extra or [])]

    def deployment(self, role: str, args: list[str], name: str | None = None, ident: str = "0",
                   extra_labels: dict | None = None) -> dict:
        selector = {**self.labels, "app.kubernetes.io/component": role, **(extra_labels or {})}
        template = self.pod(role, args, ident)
        template["metadata"]["labels"].update(extra_labels or {})
        return {"apiVersion": "apps/v1", "kind": "Deployment", "metadata": self.meta(name or role, role),
                "spec": {"replicas": 1, "selector": {"matchLabels": selector}, "template": template}}

    def service(self, name: str, role: str, headless: bool = False, extra_labels: dict | None = None) -> dict:
        spec: dict = {"selector": {**self.labels, "app.kubernetes.io/component": role, **(extra_labels or {})},
                      "ports": [{"name": "zenoh", "port": ROUTER_PORT, "targetPort": ROUTER_PORT, "protocol": "TCP"}]}
        if headless:
            spec["clusterIP"] = "None"
        return {"apiVersion": "v1", "kind": "Service", "metadata": self.meta(name, role), "spec": spec}

    def routers(self) -> list[dict]:
        """Each router's Deployment and Service, the routers meshed (and spread over nodes)."""
        objects = []
        for i, name in enumerate(self.router_names):
            others = [a for j, e in enumerate(self.endpoints) if j != i for a in ("--connect", e)]  # meshed
            args = ["router", "--listen", f"{self.scheme}/0.0.0.0:{ROUTER_PORT}", "--id", str(i), *others,
                    "--swarm", self.swarm, "--scenario", IN_CONTAINER_SCENARIO]
            own = {"fxswarm/router": str(i)}  # each router's Service reaches its own pod only
            workload = self.deployment("router", args, name, str(i), own)
            if self.n_routers > 1:  # the routers on different nodes where there are several
                workload["spec"]["template"]["spec"]["topologySpreadConstraints"] = [{
                    "maxSkew": 1, "topologyKey": "kubernetes.io/hostname", "whenUnsatisfiable": "DoNotSchedule",
                    "labelSelector": {"matchLabels": {**self.labels, "app.kubernetes.io/component": "router"}}}]
            objects += [workload, self.service(name, "router", extra_labels=own)]
        return objects


def key_files(sc: Scenario) -> dict[str, list[str]]:
    """Secure mode: role -> the files of KEYS its Secret holds (never ``ca.key``)."""
    out = {role: ["ca.pem", f"{role}.pem", f"{role}.key"] for role in ("router", "world", "leader", "logger")}
    out["router"].append("access.json")
    out["agent"] = ["ca.pem", *(f"agent-{r.id}.{ext}" for r in sc.robots for ext in ("pem", "key"))]
    return out


def secret_object(name: str, metadata: dict, keys: Path, files: list[str]) -> dict:
    """An Opaque Secret holding ``files`` of the folder ``keys``."""
    data = {f: base64.b64encode((keys / f).read_bytes()).decode() for f in files}
    return {"apiVersion": "v1", "kind": "Secret", "metadata": {**metadata, "name": name}, "type": "Opaque",
            "data": data}


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit, plan_or_exit

    sc = load_or_exit(args.config)
    check_ids(sc)
    plan = plan_or_exit(sc, args.fault, dict(os.environ))  # this edge also reads FXSWARM_FAULTS
    swarm = dns_name(args.swarm or sc.name)
    keys = checked_keys(sc, args.secure, "k8s") if args.secure else None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    law = law_module(sc)
    files = manifests(sc, Path(args.config).read_text(), swarm, args.tag, args.clock, args.wait_for, plan, keys,
                      (law[0], law[1].read_text()) if law is not None else None, args.routers)
    how = "kubectl apply -k DIR" if args.kustomize else "kubectl apply -f DIR"
    head = header(sc, f"k8s {args.config}", f"Apply: {how}; images fxswarm-<role> from docker/build-images.sh, "
                  "pushed to a registry or loaded into the cluster's nodes")
    for name, objects in files.items():
        text = head + "---\n".join(dump_yaml(o, "") for o in objects)
        if name == "secrets.yaml":  # private keys: readable by this user only, never even briefly by others
            fd = os.open(out / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.fchmod(fd, 0o600)
            with os.fdopen(fd, "w") as f:
                f.write(text)
        else:
            (out / name).write_text(text)
    if args.kustomize:
        kustomization = {"apiVersion": "kustomize.config.k8s.io/v1beta1", "kind": "Kustomization",
                         "labels": [{"pairs": {"fxswarm/swarm": swarm}}], "resources": list(files)}
        (out / "kustomization.yaml").write_text(dump_yaml(kustomization, head))
    print(f"wrote {len(files)} manifests into {out} ({sc.n} agents as one StatefulSet); apply with: "
          f"{how.replace('DIR', str(out))}", file=sys.stderr)
    return 0
