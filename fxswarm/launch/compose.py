"""``fxswarm compose CONFIG``: a docker-compose file that runs a scenario as containers.

One image per role family (``IMAGES``: each role folder's ``Dockerfile``;
the router runs from the world's image); one service per process:
``router`` (a Zenoh router), ``logger``, ``leader``, ``agent-<i>`` for each
robot and ``world``, every one a Zenoh client of the router (UDP multicast
scouting does not cross Docker's bridge network, notes/zenoh.md). The first
service of each image builds it (``docker/build-images.sh`` builds them all
ahead); the others of its family start after it, so compose never tries to
pull an image from a registry. Containers run as the image's unprivileged
user unless ``FXSWARM_USER`` says otherwise.

Start order without sleeps: the clients wait for the router themselves
(their connect timeout); the world waits, on liveliness, for the leader and
every agent (``fxswarm world`` does), and compose holds the world back until
the logger's health check passes, so the recording starts at tick 0. Every
health check is ``fxswarm health ROLE ID``: the service's own liveliness
token, asked of the router (:mod:`fxswarm.runtime.health`).

Faults: the writer resolves the scenario's ``[faults]``, its own ``--fault``
flags and ``FXSWARM_FAULTS`` (``;``-separated specs, as ``--fault`` takes
them, read from the writer's environment) into one plan, written into the
file as ``FXSWARM_FAULT_PLAN``: every service receives that same plan. A
``FXSWARM_FAULTS`` set at ``up`` instead is refused by every role process
(exit 2): regenerate the file with it.

Compose substitutes these variables from the environment (or an ``.env``
file beside the compose file) when it starts the swarm:

=========================  ====================================================
``FXSWARM_SWARM``          swarm name (key prefix; default: the scenario's name)
``FXSWARM_CLOCK``          ``lockstep`` (default) or ``realtime``
``FXSWARM_SPEED``          real time: simulation seconds per wall second (1)
``FXSWARM_TICK_TIMEOUT``   lock-step: seconds the world waits for a live agent's command (5)
``FXSWARM_RUN``            run folder under ``./runs`` (default ``<scenario>-compose``)
``FXSWARM_RERUN``          the logger's ``--rerun`` outputs (default ``file``)
``FXSWARM_SCENARIO``       scenario file mounted into every container
``FXSWARM_TAG``            tag of the role images ``fxswarm-<role>`` (default ``latest``)
``FXSWARM_BASE_IMAGE``     base of the agent, world and leader images (default the
                           local ``fxswarm-base-core:bookworm`` of
                           docker/build-base-image.sh; with a registry: ``python:3.11-slim``)
``FXSWARM_LOGGER_BASE``    base of the logger image (default ``fxswarm-base-logger:bookworm``;
                           with a registry: ``python:3.11-slim``)
``FXSWARM_USER``           user the containers run as (default the images' ``fxswarm``,
                           uid 10001): ``$(id -u):$(id -g)`` makes ``./runs`` yours
``FXSWARM_ROUTER_PUBLISH`` host address:port the router is published on
                           (default ``127.0.0.1:7447``)
``FXSWARM_UID``,           secure mode: the user the containers run as (default
``FXSWARM_GID``            10001, the image's): it must read the key files
                           (mode 0600) and write ``./runs``
=========================  ====================================================

Secure mode (``--secure KEYS``, docs/security.md): every link is mutual TLS
(``tls/router:7447``), the router enforces ``KEYS/access.json`` (rewritten
from the scenario), and each service gets only its own key, as compose
secrets (``file:`` sources in KEYS, mounted under ``/run/secrets``; never in
an image): ``ca.pem``, ``NAME.pem``, ``NAME.key`` (the router also
``access.json``).

The file is plain YAML written by :func:`render` (no YAML library needed):
keys are bare words, every scalar a JSON string, which YAML reads as is.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from fxswarm.core.scenario import Scenario
from fxswarm.faults.plan import CLI_HELP as FAULT_HELP
from fxswarm.faults.plan import FAULTS_ENV, PLAN_ENV, FaultPlan, dumps, plan_of

ROUTER_PORT = 7447
#: What the images hold (the role Dockerfiles and docker/install-role.sh), for every launcher:
#: where the scenario is mounted, where a run is written (the images' volume) ...
IN_CONTAINER_SCENARIO = "/app/scenario.toml"
IN_CONTAINER_RUNS = "/app/runs"
#: ... where a user's law module travels (on the containers' PYTHONPATH: docs/controllers.md) ...
IN_CONTAINER_LAW = "/app/law"
#: ... the unprivileged user every process runs as ...
USER_ID = 10001
#: ... and, in secure mode, where each container finds its keys (compose and Swarm mount secrets there).
SECRETS_DIR = "/run/secrets"
#: Health checks cost a Python start each (~0.2 s of CPU): often only where compose waits on one.
HEALTH_INTERVAL_S = 10
WAITED_ON_INTERVAL_S = 2
#: Image family of each role command: (image name, Dockerfile from the build context, base variable).
IMAGES: dict[str, tuple[str, str, str]] = {
    "agent": ("fxswarm-agent", "agents/Dockerfile", "FXSWARM_BASE_IMAGE"),
    "leader": ("fxswarm-leader", "leader/Dockerfile", "FXSWARM_BASE_IMAGE"),
    "world": ("fxswarm-world", "world/Dockerfile", "FXSWARM_BASE_IMAGE"),
    "router": ("fxswarm-world", "world/Dockerfile", "FXSWARM_BASE_IMAGE"),  # the runtime is in every image
    "logger": ("fxswarm-logger", "logger/Dockerfile", "FXSWARM_LOGGER_BASE"),
}
BASE_DEFAULTS = {"FXSWARM_BASE_IMAGE": "fxswarm-base-core:bookworm",
                 "FXSWARM_LOGGER_BASE": "fxswarm-base-logger:bookworm"}


def image(role: str, tag: str = "latest") -> str:
    """The image a role runs from, ``fxswarm-<family>:<tag>``."""
    return f"{IMAGES[role][0]}:{tag}"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("-o", "--output", default="-",
                   help="compose file to write (default: stdout); paths inside it are relative to its folder")
    p.add_argument("--context", default=None,
                   help="build context: the fxswarm source folder with the Dockerfile "
                        "(default: the current folder)")
    add_fault_and_secure_arguments(p, "service", "each service gets its own key as a compose secret")


def add_fault_and_secure_arguments(p: argparse.ArgumentParser, unit: str, keys_how: str) -> None:
    """``--fault`` and ``--secure`` as every deployment writer (compose, stack, k8s) takes them."""
    p.add_argument("--fault", action="append", default=None, metavar="SPEC",
                   help=FAULT_HELP + f"; resolved with the scenario's [faults] and ${FAULTS_ENV} into the one plan "
                                     f"every {unit} receives (${PLAN_ENV})")
    p.add_argument("--secure", default=None, metavar="KEYS",
                   help=f"keys folder from `fxswarm keys KEYS CONFIG`: mutual TLS and per-process rights; {keys_how} "
                        f"(docs/security.md)")


def var(name: str, default: str) -> str:
    """A compose substitution ``${NAME:-default}`` (taken from the environment at ``up``)."""
    return "${" + name + ":-" + default + "}"


def relative_path(path: Path, start: Path) -> str:
    """``path`` as a file in folder ``start`` names it (``./x``, ``../x``): compose and stack files."""
    rel = os.path.relpath(path.resolve(), start.resolve())
    if rel == ".":
        return rel
    return rel if rel.startswith("..") or rel.startswith("/") else "./" + rel


def law_module(sc: Scenario) -> tuple[str, Path] | None:
    """``(module, file)`` of the scenario's law if it is ``module:Class`` with ``module.py`` beside
    the scenario (what the containers must be given); None for a built-in or registered law, or a
    module found elsewhere (installed: it must be in the image, docs/controllers.md)."""
    from fxswarm.core.laws import registered_laws

    if sc.law in registered_laws() or sc.law_folder is None:
        return None
    module = sc.law.partition(":")[0]
    path = Path(sc.law_folder) / f"{module}.py"
    return (module, path) if "." not in module and path.is_file() else None


def _health(role: str, ident: int, interval: int = HEALTH_INTERVAL_S) -> dict:
    # timeout: one check took 8 s on a 2-core host at load 20 (Python, Zenoh session, query);
    # start_period: a success ends it at once, and the logger took over 60 s to start at load 30.
    return {"test": ["CMD", "fxswarm", "health", role, str(ident), "--quiet"],
            "interval": f"{interval}s", "timeout": "15s", "retries": 3, "start_period": "300s"}


def _with_image(service: str, role_name: str, body: dict, tag: str, context: str, built: dict[str, str]) -> dict:
    """``body`` with its image: the first service of an image builds it (``built``: image ->
    that service), the others start after it."""
    name, dockerfile, base = IMAGES[role_name]
    head: dict = {"image": image(role_name, tag)}
    if name not in built:
        built[name] = service
        head["build"] = {"context": context, "dockerfile": dockerfile,
                         "args": {"BASE_IMAGE": var(base, BASE_DEFAULTS[base])}}
    head["user"] = var("FXSWARM_USER", "fxswarm")
    body = {**head, **body}
    if built[name] != service:  # start after the service that builds the image
        depends = dict(body.get("depends_on", {}))
        depends.setdefault(built[name], {"condition": "service_started"})
        body["depends_on"] = depends
    return body


def services(scenario: Scenario, scenario_path: str, context: str, plan: FaultPlan | None = None,
             keys: str | None = None, law_folder: str | None = None) -> dict:
    """The compose document for ``scenario`` as a dict (ordered as it will be written).

    ``scenario_path``, ``context``, ``keys`` (secure mode's keys folder, or None) and
    ``law_folder`` (the scenario's folder when its law is a module beside it, or None: mounted
    read-only on every role's PYTHONPATH) are as the compose file should name them (relative to
    the compose file's folder); ``plan``: the run's resolved fault plan (default: the
    scenario's ``[faults]``), handed to every service.
    """
    plan_json = dumps(plan if plan is not None else plan_of(scenario), scenario).replace("$", "$$")
    scheme = "tls" if keys else "tcp"
    swarm = var("FXSWARM_SWARM", scenario.name)
    tag = var("FXSWARM_TAG", "latest")
    built: dict[str, str] = {}  # image -> the service that builds it

    def with_image(service: str, role_name: str, body: dict) -> dict:
        return _with_image(service, role_name, body, tag, context, built)
    run = var("FXSWARM_RUN", f"{scenario.name}-compose")
    runs_volume = f"./runs:{IN_CONTAINER_RUNS}"
    volumes = [f"{var('FXSWARM_SCENARIO', scenario_path)}:{IN_CONTAINER_SCENARIO}:ro", runs_volume]
    # FXSWARM_FAULTS is passed through only so that a role process can refuse one set at `up`.
    environment = {"FXSWARM_SWARM": swarm, PLAN_ENV: plan_json, FAULTS_ENV: var(FAULTS_ENV, ""),
                   "FXSWARM_CONNECT": f"{scheme}/router:{ROUTER_PORT}"}
    if keys:
        environment["FXSWARM_SECURE"] = SECRETS_DIR  # every command and health check takes its files there
    role_volumes, role_environment = list(volumes), dict(environment)
    if law_folder is not None:  # every role loads the scenario, and so imports its law
        role_volumes.append(f"{law_folder}:{IN_CONTAINER_LAW}:ro")
        role_environment["PYTHONPATH"] = IN_CONTAINER_LAW

    def role(name: str, ident: int, extra: list[str] | None = None, depends: dict | None = None,
             interval: int = HEALTH_INTERVAL_S) -> dict:
        command = [name, IN_CONTAINER_SCENARIO,
                   "--mode", "client", "--connect", f"{scheme}/router:{ROUTER_PORT}", "--no-multicast",
                   "--swarm", swarm,
                   "--clock", var("FXSWARM_CLOCK", "lockstep"), "--speed", var("FXSWARM_SPEED", "1"),
                   "--out", f"{IN_CONTAINER_RUNS}/{run}", *(extra or [])]
        return {"command": command, "environment": dict(role_environment),
                "volumes": list(role_volumes),
                "depends_on": depends or {"router": {"condition": "service_started"}},
                "healthcheck": _health(name, ident, interval)}

    out: dict = {
        "router": with_image("router", "router", {
            "command": ["router", "--listen", f"{scheme}/0.0.0.0:{ROUTER_PORT}", "--swarm", swarm],
            "environment": dict(environment),
            "ports": [f"{var('FXSWARM_ROUTER_PUBLISH', f'127.0.0.1:{ROUTER_PORT}')}:{ROUTER_PORT}"],
            # Writes nothing there, but its image declares the volume: unmounted, every `up` would
            # leave an anonymous volume behind.
            "volumes": [runs_volume],
            "healthcheck": _health("router", 0),
        }),
        "logger": with_image("logger", "logger", role("logger", 0, ["--rerun", var("FXSWARM_RERUN", "file")],
                                                     interval=WAITED_ON_INTERVAL_S)),
        "leader": with_image("leader", "leader", role("leader", 0)),
    }
    for robot in scenario.robots:
        out[f"agent-{robot.id}"] = with_image(f"agent-{robot.id}", "agent",
                                              role("agent", robot.id, ["--id", str(robot.id)]))
    # The world starts the clock: after the logger is recording; it waits for leader and agents itself.
    # A lock-step tick waits this long for a live agent's command (a dead one is not waited for:
    # liveliness says it is gone): long, since a loaded host stalls containers for a second or more.
    out["world"] = with_image("world", "world", role(
        "world", 0, ["--tick-timeout", var("FXSWARM_TICK_TIMEOUT", "5")],
        depends={"router": {"condition": "service_started"}, "logger": {"condition": "service_healthy"}}))
    if not keys:
        return {"services": out}
    return secure_services(out, scenario, keys)


def secure_services(out: dict, scenario: Scenario, keys: str) -> dict:
    """Secure mode: each service its own key as compose secrets, a user that can read them.

    Secrets are the ``file:`` kind: compose mounts each file read-only under /run/secrets
    (never copied into an image). With docker-compose 1.x (no swarm) the mount keeps the
    file's owner and mode: the container's user (FXSWARM_UID) must be able to read it.
    """
    secrets: dict = {"ca.pem": {"file": f"{keys}/ca.pem"}}
    for service, spec in out.items():
        name = service  # router, logger, leader, world, agent-<i>: the certificate's common name
        own = [f"{name}.pem", f"{name}.key"] + (["access.json"] if name == "router" else [])
        for s in own:
            secrets[s] = {"file": f"{keys}/{s}"}
        spec["secrets"] = ["ca.pem", *own]
        spec["user"] = var("FXSWARM_UID", str(USER_ID)) + ":" + var("FXSWARM_GID", str(USER_ID))
        # A TLS handshake and a Python start on a loaded host can outlast health's default 2 s:
        # give it most of the check's 5 s, and a few more tries before "unhealthy".
        spec["healthcheck"]["test"] = [*spec["healthcheck"]["test"], "--timeout", "4"]
        spec["healthcheck"]["retries"] = 5
    return {"services": out, "secrets": secrets}


def header(scenario: Scenario, config_arg: str) -> str:
    return (f"# Generated by `fxswarm compose {config_arg}` ({scenario.n} robots): edit the scenario, not this file.\n"
            "# Start: docker-compose up --exit-code-from world   (or: docker compose up --exit-code-from world)\n"
            "# Images: docker/build-images.sh (no registry needed), or let compose build them.\n"
            "# The run lands in ./runs/$FXSWARM_RUN (writable by uid 10001, or set FXSWARM_USER=$(id -u):$(id -g)).\n"
            "# Variables: see fxswarm/launch/compose.py (FXSWARM_SWARM, FXSWARM_CLOCK, ...). Faults: regenerate\n"
            "#   with `fxswarm compose CONFIG --fault SPEC` (or FXSWARM_FAULTS set then): FXSWARM_FAULT_PLAN.\n")


def render(doc: dict, indent: int = 0) -> str:
    """YAML for nested dicts/lists of str/int: bare keys, JSON-quoted strings, flow-style lists."""
    pad = "  " * indent
    lines: list[str] = []
    for key, value in doc.items():
        if isinstance(value, dict):
            lines.append(f"{pad}{key}:")
            lines.append(render(value, indent + 1).rstrip("\n"))
        elif isinstance(value, list):
            lines.extend(_flow_list(f"{pad}{key}: ", [_scalar(v) for v in value], pad + "  "))
        else:
            lines.append(f"{pad}{key}: {_scalar(value)}")
        if indent == 1 and isinstance(value, dict):
            lines.append("")  # a blank line between services
    return "\n".join(lines) + "\n"


def _flow_list(head: str, items: list[str], pad: str, width: int = 100) -> list[str]:
    """``head[a, b, ...]`` as a YAML flow sequence, wrapped at ``width`` columns."""
    lines, line = [], head + "["
    for k, item in enumerate(items):
        piece = item + ("," if k < len(items) - 1 else "]")
        if len(line) + len(piece) + 1 > width and not line.endswith("["):
            lines.append(line.rstrip())
            line = pad + "  "
        line += piece + " "
    lines.append(line.rstrip())
    return lines


def _scalar(value) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise TypeError(f"compose render: expected str or int, got {value!r}")
    return str(value) if isinstance(value, int) else json.dumps(value)


def compose_file(scenario: Scenario, config_arg: str, output_dir: Path, context: Path,
                 plan: FaultPlan | None = None, keys: Path | None = None) -> str:
    """The whole compose file's text for ``scenario`` written into ``output_dir``."""
    law = law_module(scenario)
    doc = services(scenario, relative_path(Path(scenario.source), output_dir), relative_path(context, output_dir),
                   plan, relative_path(keys, output_dir) if keys is not None else None,
                   relative_path(law[1].parent, output_dir) if law is not None else None)
    return header(scenario, config_arg) + "\n" + render(doc).rstrip("\n") + "\n"


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.config import load_or_exit, plan_or_exit

    sc = load_or_exit(args.config)
    plan = plan_or_exit(sc, args.fault, dict(os.environ))  # this edge also reads FXSWARM_FAULTS
    out_dir = Path.cwd() if args.output == "-" else Path(args.output).parent
    keys = None
    if args.secure:
        keys = Path(args.secure)
        from fxswarm.runtime.tls import KeyFileError, checked
        from fxswarm.security.keys import write_access
        from fxswarm.security.policy import process_names

        try:
            for name in process_names(sc):
                checked(keys, name)
        except KeyFileError as exc:
            print(f"fxswarm compose: --secure: {exc}", file=sys.stderr)
            return 2
        write_access(keys / "access.json", sc)  # the rules of this scenario as it is now
    text = compose_file(sc, args.config, out_dir, Path(args.context or "."), plan, keys)
    if args.output == "-":
        sys.stdout.write(text)
    else:
        Path(args.output).write_text(text)
        print(f"wrote {args.output} ({sc.n} agents); start it with: docker-compose -f {args.output} "
              f"up --exit-code-from world", file=sys.stderr)
    return 0
