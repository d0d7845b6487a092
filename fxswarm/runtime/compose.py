"""``fxswarm compose CONFIG``: a docker-compose file that runs a scenario as containers.

One image (the top-level ``Dockerfile``) for every role; one service per
process: ``router`` (a Zenoh router), ``logger``, ``leader``, ``agent-<i>``
for each robot and ``world``, every one a Zenoh client of the router (UDP
multicast scouting does not cross Docker's bridge network, notes/zenoh.md).

Start order without sleeps: the clients wait for the router themselves
(their connect timeout); the world waits, on liveliness, for the leader and
every agent (``fxswarm world`` does), and compose holds the world back until
the logger's health check passes, so the recording starts at tick 0. Every
health check is ``fxswarm health ROLE ID``: the service's own liveliness
token, asked of the router (:mod:`fxswarm.runtime.health`).

Compose substitutes these variables from the environment (or an ``.env``
file beside the compose file) when it starts the swarm:

=========================  ====================================================
``FXSWARM_SWARM``          swarm name (key prefix; default: the scenario's name)
``FXSWARM_CLOCK``          ``lockstep`` (default) or ``realtime``
``FXSWARM_SPEED``          real time: simulation seconds per wall second (1)
``FXSWARM_TICK_TIMEOUT``   lock-step: seconds the world waits for a live agent's command (5)
``FXSWARM_FAULTS``         fault specs, ``;``-separated, as ``--fault`` takes them
                           (e.g. ``agent:*->agent:4 drop=0.2; partition 5-8 isolate=3``)
``FXSWARM_RUN``            run folder under ``./runs`` (default ``<scenario>-compose``)
``FXSWARM_RERUN``          the logger's ``--rerun`` outputs (default ``file``)
``FXSWARM_SCENARIO``       scenario file mounted into every container
``FXSWARM_IMAGE``          image to run (default ``fxswarm:latest``)
``FXSWARM_BASE_IMAGE``     base image the router service builds it from
                           (default ``python:3.11-slim``; no registry:
                           ``fxswarm-base:bookworm`` from docker/build-base-image.sh)
``FXSWARM_ROUTER_PUBLISH`` host address:port the router is published on
                           (default ``127.0.0.1:7447``)
=========================  ====================================================

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

ROUTER_PORT = 7447
IN_CONTAINER_SCENARIO = "/app/scenario.toml"
IN_CONTAINER_RUNS = "/app/runs"
#: Health checks cost a Python start each (~0.2 s of CPU): often only where compose waits on one.
HEALTH_INTERVAL_S = 10
WAITED_ON_INTERVAL_S = 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="scenario file (TOML)")
    p.add_argument("-o", "--output", default="-",
                   help="compose file to write (default: stdout); paths inside it are relative to its folder")
    p.add_argument("--context", default=None,
                   help="build context: the fxswarm source folder with the Dockerfile "
                        "(default: the current folder)")


def var(name: str, default: str) -> str:
    """A compose substitution ``${NAME:-default}`` (taken from the environment at ``up``)."""
    return "${" + name + ":-" + default + "}"


def _relative(path: Path, start: Path) -> str:
    rel = os.path.relpath(path.resolve(), start.resolve())
    if rel == ".":
        return rel
    return rel if rel.startswith("..") or rel.startswith("/") else "./" + rel


def services(scenario: Scenario, scenario_path: str, context: str) -> dict:
    """The compose document for ``scenario`` as a dict (ordered as it will be written).

    ``scenario_path`` and ``context`` are as the compose file should name them
    (relative to the compose file's folder).
    """
    swarm = var("FXSWARM_SWARM", scenario.name)
    image = var("FXSWARM_IMAGE", "fxswarm:latest")
    run = var("FXSWARM_RUN", f"{scenario.name}-compose")
    volumes = [f"{var('FXSWARM_SCENARIO', scenario_path)}:{IN_CONTAINER_SCENARIO}:ro",
               f"./runs:{IN_CONTAINER_RUNS}"]
    environment = {"FXSWARM_SWARM": swarm, "FXSWARM_FAULTS": var("FXSWARM_FAULTS", ""),
                   "FXSWARM_CONNECT": f"tcp/router:{ROUTER_PORT}"}

    def health(role: str, ident: int, interval: int = HEALTH_INTERVAL_S) -> dict:
        return {"test": ["CMD", "fxswarm", "health", role, str(ident), "--quiet"],
                "interval": f"{interval}s", "timeout": "5s", "retries": 3, "start_period": "60s"}

    def role(name: str, ident: int, extra: list[str] | None = None, depends: dict | None = None,
             interval: int = HEALTH_INTERVAL_S) -> dict:
        command = [name, IN_CONTAINER_SCENARIO,
                   "--mode", "client", "--connect", f"tcp/router:{ROUTER_PORT}", "--no-multicast",
                   "--swarm", swarm,
                   "--clock", var("FXSWARM_CLOCK", "lockstep"), "--speed", var("FXSWARM_SPEED", "1"),
                   "--out", f"{IN_CONTAINER_RUNS}/{run}", *(extra or [])]
        return {"image": image, "command": command, "environment": dict(environment),
                "volumes": list(volumes),
                "depends_on": depends or {"router": {"condition": "service_started"}},
                "healthcheck": health(name, ident, interval)}

    out: dict = {
        "router": {
            "image": image,
            # Only this service builds the image; the others run it (they all start after it).
            "build": {"context": context, "args": {"BASE_IMAGE": var("FXSWARM_BASE_IMAGE", "python:3.11-slim")}},
            "command": ["router", "--listen", f"tcp/0.0.0.0:{ROUTER_PORT}", "--swarm", swarm],
            "environment": dict(environment),
            "ports": [f"{var('FXSWARM_ROUTER_PUBLISH', f'127.0.0.1:{ROUTER_PORT}')}:{ROUTER_PORT}"],
            "healthcheck": health("router", 0),
        },
        "logger": role("logger", 0, ["--rerun", var("FXSWARM_RERUN", "file")], interval=WAITED_ON_INTERVAL_S),
        "leader": role("leader", 0),
    }
    for robot in scenario.robots:
        out[f"agent-{robot.id}"] = role("agent", robot.id, ["--id", str(robot.id)])
    # The world starts the clock: after the logger is recording; it waits for leader and agents itself.
    # A lock-step tick waits this long for a live agent's command (a dead one is not waited for:
    # liveliness says it is gone): long, since a loaded host stalls containers for a second or more.
    out["world"] = role("world", 0, ["--tick-timeout", var("FXSWARM_TICK_TIMEOUT", "5")],
                        depends={"router": {"condition": "service_started"},
                                 "logger": {"condition": "service_healthy"}})
    return {"services": out}


def header(scenario: Scenario, config_arg: str) -> str:
    return (f"# Generated by `fxswarm compose {config_arg}` ({scenario.n} robots): edit the scenario, not this file.\n"
            "# Start: docker-compose up --exit-code-from world   (or: docker compose up --exit-code-from world)\n"
            "# Without an image registry, first: docker/build-base-image.sh\n"
            "#   and set FXSWARM_BASE_IMAGE=fxswarm-base:bookworm. The run lands in ./runs/$FXSWARM_RUN.\n"
            "# Variables: see fxswarm/runtime/compose.py (FXSWARM_SWARM, FXSWARM_CLOCK, FXSWARM_FAULTS, ...).\n")


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


def compose_file(scenario: Scenario, config_arg: str, output_dir: Path, context: Path) -> str:
    """The whole compose file's text for ``scenario`` written into ``output_dir``."""
    doc = services(scenario, _relative(Path(scenario.source), output_dir), _relative(context, output_dir))
    return header(scenario, config_arg) + "\n" + render(doc).rstrip("\n") + "\n"


def main(args: argparse.Namespace) -> int:
    from fxswarm.runtime.sim_cli import load_or_exit

    sc = load_or_exit(args.config)
    out_dir = Path.cwd() if args.output == "-" else Path(args.output).parent
    text = compose_file(sc, args.config, out_dir, Path(args.context or "."))
    if args.output == "-":
        sys.stdout.write(text)
    else:
        Path(args.output).write_text(text)
        print(f"wrote {args.output} ({sc.n} agents); start it with: docker-compose -f {args.output} "
              f"up --exit-code-from world", file=sys.stderr)
    return 0
