"""Who may read and who may serve the run's record (``world/record``), with real processes.

A router (``fxswarm router``, plain or ``--secure``) and processes each holding one certificate
of ``fxswarm keys`` (``record_peer.py``): the world serves the record, the observer (``fxswarm
attach``'s certificate) fetches it. Secure, robot 2's key can neither read it nor serve a forged
one; on a plain router both attacks land, so the test can fail.
"""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from fxswarm.core.scenario import load
from fxswarm.launch.launcher import free_port
from fxswarm.runtime.tls import checked
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions, wait_until
from fxswarm.security.keys import write_keys

from support import PAPER_FAST

pytestmark = [pytest.mark.zenoh, pytest.mark.timeout(300)]

PEER = Path(__file__).with_name("record_peer.py")


@pytest.fixture(scope="module")
def keys(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("keys")
    write_keys(folder, load(PAPER_FAST))
    return folder


class Swarm:
    def __init__(self, tmp_path: Path, keys: Path | None) -> None:
        self.keys = keys
        self.swarm = f"rec-{uuid.uuid4().hex[:8]}"
        self.endpoint = f"{'tls' if keys else 'tcp'}/127.0.0.1:{free_port()}"
        argv = [sys.executable, "-m", "fxswarm.cli", "router", "--listen", self.endpoint, "--swarm", self.swarm]
        if keys:
            argv += ["--secure", str(keys)]
        self.router = subprocess.Popen(argv, stdout=(tmp_path / "router.log").open("w"), stderr=subprocess.STDOUT)
        self.servers: list[subprocess.Popen] = []
        tls = checked(keys, "observer") if keys else None
        with ZenohBus(self.swarm, ZenohOptions("client", (self.endpoint,), (), False, connect_timeout_ms=60_000,
                                               tls=tls)) as bus:
            up: list[str] = []
            bus.watch_alive("router/0", lambda name, is_up: up.append(name))
            assert wait_until(bus, lambda: up, 60), "the router never came up"

    def argv(self, name: str) -> list[str]:
        out = [sys.executable, str(PEER), "--connect", self.endpoint, "--swarm", self.swarm, "--as", name]
        return out + (["--keys", str(self.keys)] if self.keys else [])

    def serve(self, name: str, ticks: int) -> subprocess.Popen:
        p = subprocess.Popen([*self.argv(name), "serve", "--ticks", str(ticks)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
        self.servers.append(p)
        assert p.stdout.readline().strip() == "serving"
        return p

    def fetch(self, name: str) -> dict:
        r = subprocess.run([*self.argv(name), "fetch", "--timeout", "5"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr[-2000:]
        return json.loads(r.stdout.strip().splitlines()[-1])

    @staticmethod
    def stop(server: subprocess.Popen) -> None:
        server.stdin.close()
        assert server.wait(30) == 0

    def close(self) -> None:
        for p in self.servers:
            if p.poll() is None:
                p.kill()
                p.wait()
        self.router.terminate()
        self.router.wait(30)


@pytest.mark.parametrize("secure", [True, False], ids=["secure", "plain"])
def test_only_the_observer_reads_the_worlds_record_and_only_the_world_serves_one(tmp_path, keys, secure):
    swarm = Swarm(tmp_path, keys if secure else None)
    try:
        world = swarm.serve("world", ticks=4000)  # 4000 ticks of t: several 256-byte parts
        got = swarm.fetch("observer")
        assert got == {"ok": True, "who": "world", "ticks": 4000, "error": None}, got
        stolen = swarm.fetch("agent-2")  # a robot reading the run's record
        swarm.stop(world)
        forger = swarm.serve("agent-2", ticks=5)  # a robot serving a forged record
        forged = swarm.fetch("observer")
        swarm.stop(forger)
    finally:
        swarm.close()
    if secure:
        assert not stolen["ok"] and not forged["ok"], (stolen, forged)
    else:  # the same attacks land without the rules
        assert stolen["ok"] and stolen["who"] == "world", stolen
        assert forged["ok"] and forged["who"] == "agent-2", forged
