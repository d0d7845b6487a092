"""Docker Swarm: image sizes and the stack's start-up time (deploy -> every process alive).

    python benchmarks/bench_stack.py [--config configs/large.toml] [--repeat 1] [--out benchmarks/results/stack.json]

Needs a Docker engine and the role images (docker/build-images.sh; ``FXSWARM_TAG`` picks the
tag). An engine not in swarm mode is made a single-node swarm for the benchmark and left again
at the end (with the docker_gwbridge network that init makes). Each repeat deploys ``fxswarm
stack CONFIG`` under a unique name, times ``docker stack deploy`` until the router answers, then
until the world, the leader, the logger and every agent hold their liveliness token, and until
the world's clock has started (its first state), as a Zenoh client of the router's published
port sees them; then removes the stack (and its volume), timing that too, and waits until
nothing of it is left. Each run records the load average before it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from bench_io import machine, write_json

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def sh(*cmd: str, env: dict | None = None) -> str:
    return subprocess.run(cmd, capture_output=True, text=True, check=True, env=env).stdout


def swarm_state() -> str:
    return sh("docker", "info", "--format", "{{.Swarm.LocalNodeState}}").strip()


def networks() -> set[str]:
    return set(sh("docker", "network", "ls", "--format", "{{.Name}}").split())


def image_sizes(tag: str) -> dict:
    out = {}
    for role in ("agent", "world", "leader", "logger"):
        size = int(sh("docker", "image", "inspect", "-f", "{{.Size}}", f"fxswarm-{role}:{tag}"))
        out[f"fxswarm-{role}:{tag}"] = round(size / 1e6)
    return out


def one_start(config: str, tag: str) -> dict:
    from fxswarm.launch.launcher import free_port
    from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions
    from fxswarm.core.scenario import load

    sc = load(config)
    stack = f"fxbench{uuid.uuid4().hex[:8]}"
    port = free_port()
    folder = Path(tempfile.mkdtemp(prefix="fxswarm-bench-stack-"))
    sh(sys.executable, "-m", "fxswarm.cli", "stack", config, "--out", str(folder), "--swarm", stack)
    env = {**os.environ, "FXSWARM_TAG": tag, "FXSWARM_ROUTER_PORT": str(port), "FXSWARM_CLOCK": "realtime"}
    alive: set[str] = set()
    first_state: list[float] = []
    load = round(os.getloadavg()[0], 2)
    t0 = time.monotonic()
    bus = None
    try:
        sh("docker", "stack", "deploy", "-c", str(folder / "stack.yml"), stack, env=env)
        deployed = time.monotonic() - t0
        bus = ZenohBus(stack, ZenohOptions("client", (f"tcp/127.0.0.1:{port}",), (), False,
                                           connect_timeout_ms=600_000))
        router = time.monotonic() - t0
        bus.watch_alive("*/*", lambda name, up: (alive.add if up else alive.discard)(name))
        bus.subscribe("world/state", lambda *_: first_state.append(time.monotonic()) if not first_state else None)
        needed = {"leader/0", "logger/0", "world/0", *(f"agent/{r.id}" for r in sc.robots)}
        end = t0 + 900
        while not needed <= alive and time.monotonic() < end:
            bus.poll(0.1)
        if not needed <= alive:
            raise SystemExit(f"not all alive after 900 s: missing {sorted(needed - alive)}")
        everyone = time.monotonic() - t0
        while not first_state and time.monotonic() < end:
            bus.poll(0.1)
        if not first_state:
            raise SystemExit("every process alive, but no state from the world after 900 s")
        result = {"robots": sc.n, "load_avg_before": load, "deploy_cmd_s": round(deployed, 2),
                  "router_s": round(router, 2), "all_alive_s": round(everyone, 2),
                  "first_state_s": round(first_state[0] - t0, 2)}
    finally:
        if bus is not None:
            bus.close()
        removed = time.monotonic()
        subprocess.run(["docker", "stack", "rm", stack], capture_output=True)
        end = time.monotonic() + 300
        label = f"label=com.docker.stack.namespace={stack}"
        while time.monotonic() < end and (sh("docker", "ps", "-aq", "--filter", label).strip()
                                          or sh("docker", "network", "ls", "-q", "--filter", label).strip()):
            time.sleep(1)
        removed = time.monotonic() - removed
        subprocess.run(["docker", "volume", "rm", f"{stack}_runs"], capture_output=True)
        shutil.rmtree(folder, ignore_errors=True)
    result["removed_s"] = round(removed, 2)
    return result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(REPO / "configs" / "large.toml"))
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "stack.json"))
    args = p.parse_args()
    tag = os.environ.get("FXSWARM_TAG", "latest")
    result = {"machine": machine(), "tag": tag, "images_mb": image_sizes(tag),
              "config": os.path.relpath(args.config, REPO), "runs": []}
    state, found = swarm_state(), networks()
    if state == "inactive":
        sh("docker", "swarm", "init", "--advertise-addr", "127.0.0.1")
    try:
        for _ in range(args.repeat):
            result["runs"].append(one_start(args.config, tag))
            print(result["runs"][-1], file=sys.stderr)
    finally:
        if state == "inactive":  # leave the engine as found
            subprocess.run(["docker", "swarm", "leave", "--force"], capture_output=True)
            if "docker_gwbridge" not in found:
                subprocess.run(["docker", "network", "rm", "docker_gwbridge"], capture_output=True)
    for key in ("router_s", "all_alive_s", "first_state_s", "removed_s"):
        result[f"{key}_median"] = statistics.median(r[key] for r in result["runs"])
    write_json(args.out, result)
    print(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
