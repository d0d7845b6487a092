"""``fxswarm stack CONFIG --out DIR``: a Docker Swarm stack that runs a scenario on a cluster.

Writes ``DIR/stack.yml`` and ``DIR/scenario.toml`` (the scenario, handed to
every service as a Swarm config, so no node needs the file). Deploy with::

    docker stack deploy -c DIR/stack.yml NAME      # NAME: any stack name

Services (docs/deploy.md says why):

* ``router``: the Zenoh router every process is a client of, on the overlay
  network, its port published on the node it runs on (``mode: host``: the
  ingress mesh does not go with ``dnsrr``) for ``fxswarm attach``; restarted
  whatever its exit. ``--routers 2``: also ``router-1`` (published port
  ``FXSWARM_ROUTER_PORT_1``, 7448), meshed with it, kept off the node labelled
  ``fxswarm.router=0`` (and ``router`` off ``=1``); every process lists both;
* ``agent``: ONE service scaled to the scenario's robot count; each task's
  slot (``{{.Task.Slot}}``, 1..N) is its robot id, passed as ``FXSWARM_ID``
  (Swarm templates the environment, not the command; docker/entrypoint.sh
  adds ``--id``). A killed agent task fails, Swarm starts a new task in the
  same slot, and that robot rejoins the run (``restart_policy: on-failure``);
* ``world``, ``leader``, ``logger``: one task each. The world waits, on
  liveliness, for the leader, every agent and ``--wait-for`` (default the
  logger, so the recording starts at tick 0): Swarm has no start order.

Faults: the scenario's ``[faults]``, ``--fault`` flags and ``FXSWARM_FAULTS`` (read when the
file is written) resolve into one plan, written into every service's environment as
``FXSWARM_FAULT_PLAN``, as ``fxswarm compose`` does; a ``FXSWARM_FAULTS`` set at deploy instead
is refused by every role process.

Secure mode (``--secure KEYS``, docs/security.md): every link is ``tls/``, the router enforces
``KEYS/access.json``, and the keys reach the services as Swarm secrets (``docker stack deploy``
reads them from KEYS; never in an image), each service only its own (the router also
``access.json``). The agents, one scaled service, share one set of secrets holding every
robot's pair, readable by root only: the task starts as root, its entrypoint copies ``ca.pem``
and its own slot's pair into a tmpfs and drops to uid 10001 before ``fxswarm agent`` starts
(docker/entrypoint.sh; docs/security.md says what this does and does not protect).

Every service has ``endpoint_mode: dnsrr`` (the service name resolves to its
tasks' addresses; the default virtual IP gave "No route to host" on the
overlay network) and a health check from its own liveliness token
(``fxswarm health``). Runs land in the ``runs`` volume on each node.

``docker stack deploy`` substitutes from the environment: ``FXSWARM_TAG``
(image tag, ``latest``), ``FXSWARM_CLOCK`` (``lockstep``), ``FXSWARM_SPEED``
(1), ``FXSWARM_RERUN`` (``file``), ``FXSWARM_RUN`` (run folder name),
``FXSWARM_TICK_TIMEOUT`` (5) and ``FXSWARM_ROUTER_PORT`` (the router's
published port, 7447).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import FAULTS_ENV, PLAN_ENV, FaultPlan, dumps, plan_of
from fxswarm.launch.compose import (HEALTH_INTERVAL_S, IMAGES, IN_CONTAINER_LAW, IN_CONTAINER_RUNS,
                                    IN_CONTAINER_SCENARIO, ROUTER_PORT, SECRETS_DIR, USER_ID,
                                    add_fault_and_secure_arguments, image, law_module, relative_path, var)
from fxswarm.runtime.numbers import swarm_name

NETWORK = "fxswarm"
#: The world waits this long for everyone: many tasks starting on a few cores take minutes.
WAIT_TIMEOUT_S = 600
#: Secure mode: where an agent task's entrypoint puts its own pair, picked from all of them in
#: SECRETS_DIR (a tmpfs).
AGENT_KEYS_DIR = "/run/fxswarm-keys"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write stack.yml and scenario.toml into")
    p.add_argument("--swarm", type=swarm_name, default=None,
                   help="swarm name, the key-expression prefix (default: the scenario's name); two stacks "
                        "with different names share a cluster without cross-talk")
    p.add_argument("--wait-for", action="append", default=None, metavar="ROLE/ID",
                   help="what the world waits for besides the leader and agents (repeatable; default "
                        "logger/0); add observer/0 to start the clock only once `fxswarm attach` listens")
    p.add_argument("--routers", type=int, choices=(1, 2, 3), default=1,
                   help="router services, meshed with each other, each on a node of its own once nodes are "
                        "labelled fxswarm.router=<n>; every process lists them all and fails over (default 1)")
    add_fault_and_secure_arguments(p, "service", "the keys reach the services as Swarm secrets")


def router_name(i: int) -> str:
    """Router ``i``'s service (and host) name: ``router``, ``router-1``, ..."""
    return "router" if i == 0 else f"router-{i}"


def role_command(role: str, swarm: str, run: str, extra: list[str] | None = None, scheme: str = "tcp",
                 routers: int = 1) -> list[str]:
    """A role's command line in a container, as a client of the ``router`` service(s): with several,
    it lists them all (the first that answers; the next when it is lost)."""
    connect = [a for i in range(routers) for a in ("--connect", f"{scheme}/{router_name(i)}:{ROUTER_PORT}")]
    return [role, IN_CONTAINER_SCENARIO, "--mode", "client", *connect,
            "--no-multicast", "--swarm", swarm, "--clock", var("FXSWARM_CLOCK", "lockstep"),
            "--speed", var("FXSWARM_SPEED", "1"), "--out", f"{IN_CONTAINER_RUNS}/{run}", *(extra or [])]


def world_extra(wait_for: list[str]) -> list[str]:
    # --finished-ok: a run that reached its end exits 0, so Swarm (on-failure) does not start it over.
    out = ["--tick-timeout", var("FXSWARM_TICK_TIMEOUT", "5"), "--wait-timeout", str(WAIT_TIMEOUT_S), "--finished-ok"]
    for name in wait_for:
        out += ["--wait-for", name]
    return out


def _health(test: list[str]) -> dict:
    return {"test": test, "interval": f"{HEALTH_INTERVAL_S}s", "timeout": "15s", "retries": 3,
            "start_period": "300s"}


def _service(role: str, command: list[str], condition: str, tag: str, env: dict, scheme: str, law: str | None,
             ident: str = "0", replicas: int = 1, extra_env: dict | None = None) -> dict:
    """One service of the stack (see :func:`stack_document`): image, command, health check, restarts."""
    # A router restarting (Swarm restarts it) must not fail every other task's check meanwhile.
    check = (["CMD-SHELL", f'fxswarm health {role} "$$FXSWARM_ID" --quiet --router-down-ok'] if role == "agent"
             else ["CMD", "fxswarm", "health", role, ident, "--quiet",
                   *(["--router-down-ok"] if role != "router" else [])])
    if role == "router":
        # Swarm puts a task in its service's DNS only once it is healthy: the router asks itself.
        check += ["--connect", f"{scheme}/127.0.0.1:{ROUTER_PORT}"]
    out = {
        "image": image(role, tag),
        "command": command,
        "environment": {**env, **(extra_env or {})},
        "networks": [NETWORK],
        "healthcheck": _health(check),
        "deploy": {
            "replicas": replicas,
            "endpoint_mode": "dnsrr",
            # on-failure: a crashed or killed process comes back (a new task, the same slot);
            # one that finished its run (exit 0) stays down.
            "restart_policy": {"condition": condition, "delay": "1s"},
        },
    }
    out["configs"] = [{"source": "scenario", "target": IN_CONTAINER_SCENARIO, "mode": 0o444}]
    if law is not None and role != "router":  # a user's law module: a config on every role's PYTHONPATH
        out["configs"].append({"source": "law", "target": f"{IN_CONTAINER_LAW}/{law}.py", "mode": 0o444})
        out["environment"]["PYTHONPATH"] = IN_CONTAINER_LAW
    # The router too: the images declare the volume, and a task without it mounted leaves an
    # anonymous volume on its node each time it starts.
    out["volumes"] = [{"type": "volume", "source": "runs", "target": IN_CONTAINER_RUNS}]
    return out


def stack_document(sc: Scenario, swarm: str, wait_for: list[str], plan: FaultPlan | None = None,
                   keys: str | None = None, law: str | None = None, routers: int = 1) -> dict:
    """The stack file for ``sc`` as a dict (YAML-ready).

    ``plan``: the run's resolved fault plan (default: the scenario's ``[faults]``), handed to
    every service; ``keys``: secure mode's keys folder as the stack file names it (relative to
    its folder), or None; ``law``: the name of the law module beside the scenario, copied as
    ``LAW.py`` beside the stack file (:func:`fxswarm.launch.compose.law_module`), or None.
    """
    tag = var("FXSWARM_TAG", "latest")
    run = var("FXSWARM_RUN", f"{sc.name}-stack")
    scheme = "tls" if keys else "tcp"
    # `docker stack deploy` substitutes ${...} in the whole file: a literal $ is written $$.
    plan_json = dumps(plan if plan is not None else plan_of(sc), sc).replace("$", "$$")
    # FXSWARM_FAULTS is passed through only so that a role process can refuse one set at deploy.
    env = {"FXSWARM_SWARM": swarm, PLAN_ENV: plan_json, FAULTS_ENV: var(FAULTS_ENV, ""),
           "FXSWARM_CONNECT": f"{scheme}/router:{ROUTER_PORT}"}

    def service(role: str, command: list[str], condition: str, ident: str = "0", replicas: int = 1,
                extra_env: dict | None = None) -> dict:
        return _service(role, command, condition, tag, env, scheme, law, ident, replicas, extra_env)

    services = {}
    for i in range(routers):
        # Restarted whatever its exit (condition any); meshed with the other routers.
        others = [a for j in range(routers) if j != i for a in ("--connect", f"{scheme}/{router_name(j)}:{ROUTER_PORT}")]
        router = service("router", ["router", "--listen", f"{scheme}/0.0.0.0:{ROUTER_PORT}", "--id", str(i), *others,
                                    "--swarm", swarm, "--scenario", IN_CONTAINER_SCENARIO], "any", ident=str(i))
        port = var("FXSWARM_ROUTER_PORT", str(ROUTER_PORT)) if i == 0 else \
            var(f"FXSWARM_ROUTER_PORT_{i}", str(ROUTER_PORT + i))
        router["ports"] = [{"target": ROUTER_PORT, "published": port, "protocol": "tcp", "mode": "host"}]
        if routers > 1:
            # Apart once two nodes are labelled (docker node update --label-add fxswarm.router=N):
            # router i never goes where another router's label is; unlabelled nodes take any.
            router["deploy"]["placement"] = {"constraints": [f"node.labels.fxswarm.router != {j}"
                                                             for j in range(routers) if j != i]}
        services[router_name(i)] = router
    services.update({
        "logger": service("logger", role_command("logger", swarm, run, ["--rerun", var("FXSWARM_RERUN", "file")],
                                                 scheme, routers), "on-failure"),
        "leader": service("leader", role_command("leader", swarm, run, scheme=scheme, routers=routers), "on-failure"),
        "agent": service("agent", role_command("agent", swarm, run, scheme=scheme, routers=routers), "on-failure",
                         replicas=sc.n, extra_env={"FXSWARM_ID": "{{.Task.Slot}}"}),
        "world": service("world", role_command("world", swarm, run, world_extra(wait_for), scheme, routers),
                         "on-failure"),
    })
    doc = {
        "version": "3.8",
        "services": services,
        "networks": {NETWORK: {"driver": "overlay", "attachable": True}},
        "volumes": {"runs": {}},
        "configs": {"scenario": {"file": "./scenario.toml"}},
    }
    if law is not None:
        doc["configs"]["law"] = {"file": f"./{law}.py"}
    if keys:
        doc["secrets"] = secure_services(services, sc, keys)
    return doc


def secure_services(services: dict, sc: Scenario, keys: str) -> dict:
    """Secure mode: give each service its keys as Swarm secrets; return the stack's ``secrets``.

    router, world, leader, logger: ``ca.pem`` and their own pair (the router also
    ``access.json``) under /run/secrets, owned by the images' user, mode 0400. The agent
    service: ``ca.pem`` and every robot's pair, owned by root, mode 0400 (Swarm gives every
    replica of a service the same secrets, and cannot pick one by slot); the task starts as
    root and docker/entrypoint.sh copies its own slot's pair into a tmpfs, then runs
    ``fxswarm agent`` as uid 10001, which cannot read the other robots' keys.
    """
    secrets: dict = {"ca.pem": {"file": f"{keys}/ca.pem"}}

    def mount(name: str, uid: int) -> dict:
        return {"source": name, "target": name, "uid": str(uid), "gid": str(uid), "mode": 0o400}

    for role, spec in services.items():
        if role == "agent":
            own = [f"agent-{r.id}.{ext}" for r in sc.robots for ext in ("pem", "key")]
            uid = 0
            spec["user"] = "0:0"  # only to pick its key: docker/entrypoint.sh drops to FXSWARM_RUN_AS
            spec["environment"].update({"FXSWARM_AGENT_KEYS": SECRETS_DIR, "FXSWARM_SECURE": AGENT_KEYS_DIR,
                                        "FXSWARM_RUN_AS": f"{USER_ID}:{USER_ID}"})
            spec["volumes"].append({"type": "tmpfs", "target": AGENT_KEYS_DIR, "tmpfs": {"size": 1 << 20}})
        else:
            name = "router" if role.startswith("router") else role  # every router holds the router's pair
            own = [f"{name}.pem", f"{name}.key"] + (["access.json"] if name == "router" else [])
            uid = USER_ID
            spec["environment"]["FXSWARM_SECURE"] = SECRETS_DIR  # the command and the health check
        for name in own:
            secrets[name] = {"file": f"{keys}/{name}"}
        spec["secrets"] = [mount(name, uid) for name in ("ca.pem", *own)]
        # A TLS handshake and a Python start on a loaded host can outlast health's default 2 s.
        test = spec["healthcheck"]["test"]
        spec["healthcheck"]["test"] = ([test[0], test[1] + " --timeout 4"] if test[0] == "CMD-SHELL"
                                       else [*test, "--timeout", "4"])
        spec["healthcheck"]["retries"] = 5
    return secrets


def check_ids(sc: Scenario) -> None:
    """Task slots (and StatefulSet ordinals) count 1..N: the robots must be numbered so."""
    ids = [r.id for r in sc.robots]
    if ids != list(range(1, sc.n + 1)):
        raise SystemExit(f"fxswarm: {sc.source}: robots: ids must be 1..{sc.n} in order for one scaled agent "
                         f"service (its replica number is the robot id), got {ids}")


def dump_yaml(doc: dict, header: str) -> str:
    try:
        import yaml
    except ModuleNotFoundError:
        raise SystemExit("fxswarm: writing deployment files needs PyYAML: pip install 'fxswarm[deploy]'") from None
    return header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)


def header(sc: Scenario, command: str, how: str) -> str:
    return (f"# Generated by `fxswarm {command}` from {sc.source} ({sc.n} robots): edit the scenario, not this file.\n"
            f"# {how}\n# docs/deploy.md: images, variables, several hosts.\n")


def checked_keys(sc: Scenario, keys: str, who: str) -> Path:
    """KEYS, once every process of ``sc`` has usable files there, with ``access.json`` rewritten
    from the scenario as it is now; else one line naming the file and exit 2."""
    from fxswarm.runtime.tls import KeyFileError, checked
    from fxswarm.security.keys import write_access
    from fxswarm.security.policy import process_names

    folder = Path(keys)
    try:
        for name in process_names(sc):
            checked(folder, name)
    except KeyFileError as exc:
        print(f"fxswarm {who}: --secure: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    write_access(folder / "access.json", sc)
    return folder


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit, plan_or_exit

    sc = load_or_exit(args.config)
    check_ids(sc)
    plan = plan_or_exit(sc, args.fault, dict(os.environ))  # this edge also reads FXSWARM_FAULTS
    swarm = args.swarm or sc.name
    out = Path(args.out)
    keys = checked_keys(sc, args.secure, "stack") if args.secure else None
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(args.config, out / "scenario.toml")
    law = law_module(sc)
    if law is not None:
        shutil.copyfile(law[1], out / f"{law[0]}.py")
    doc = stack_document(sc, swarm, args.wait_for if args.wait_for is not None else ["logger/0"], plan,
                         relative_path(keys, out) if keys is not None else None, law[0] if law is not None else None,
                         args.routers)
    text = dump_yaml(doc, header(sc, f"stack {args.config}",
                                 f"Deploy: docker stack deploy -c stack.yml NAME   (images: docker/build-images.sh on "
                                 f"every node; {', '.join(sorted({v[0] for v in IMAGES.values()}))})"))
    (out / "stack.yml").write_text(text)
    print(f"wrote {out / 'stack.yml'} ({sc.n} agents as one service); deploy it with: "
          f"docker stack deploy -c {out / 'stack.yml'} {swarm}", file=sys.stderr)
    return 0
