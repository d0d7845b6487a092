"""Zenoh across hosts: one router per host, routers meshed, processes on their own host's router.

Two ``fxswarm router`` processes stand for two hosts' routers (router B up before A exists, so
it meshes with A by retrying: hosts start in any order); clients of different routers hear each other
(data and liveliness), and a second swarm on the same routers hears nothing of the first
(key expressions are per swarm).
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from fxswarm.launch.launcher import free_port
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions, wait_until

pytestmark = [pytest.mark.zenoh, pytest.mark.timeout(300)]


def router(port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fxswarm.cli", "router", "--listen", f"tcp/127.0.0.1:{port}",
                             "--swarm", "mesh", *extra], stderr=subprocess.PIPE, text=True)


def client(port: int, swarm: str) -> ZenohBus:
    return ZenohBus(swarm, ZenohOptions("client", (f"tcp/127.0.0.1:{port}",), (), False, connect_timeout_ms=60_000))


def test_clients_of_meshed_routers_hear_each_other_and_swarms_stay_apart():
    a, b = free_port(), free_port()
    routers = [router(b, "--connect", f"tcp/127.0.0.1:{a}")]
    buses: list[ZenohBus] = []
    try:
        # B is up (its token is declared once its session is open, after its first try to reach A)
        # before A starts: B's link to A can only come from retrying in the background.
        probe = client(b, "mesh")
        buses.append(probe)
        routers_up: set[str] = set()
        probe.watch_alive("router/*", lambda name, up: routers_up.add(name) if up else None)
        assert wait_until(probe, lambda: "router/0" in routers_up, 60), "router B did not come up"
        routers.append(router(a))
        on_a, on_b = client(a, "one"), client(b, "one")
        other_a, other_b = client(a, "two"), client(b, "two")
        buses += [on_a, on_b, other_a, other_b]
        got_b: list[bytes] = []
        got_other: list[bytes] = []
        seen_alive: set[str] = set()
        other_alive: set[str] = set()
        on_b.subscribe("agent/1/note", lambda _t, payload: got_b.append(payload), raw=True)
        on_b.watch_alive("agent/*", lambda name, up: seen_alive.add(name) if up else None)
        other_b.subscribe("agent/1/note", lambda _t, payload: got_other.append(payload), raw=True)
        other_b.watch_alive("agent/*", lambda name, up: other_alive.add(name) if up else None)
        on_a.declare_alive("agent", 1)
        # Across the mesh: liveliness first (a late subscriber gets it as history), then data.
        assert wait_until(on_b, lambda: "agent/1" in seen_alive, 60), "liveliness did not cross the routers"

        def heard(bus: ZenohBus, sink: list, sender: ZenohBus, payload: bytes) -> bool:
            sender.publish_bytes("agent/1/note", payload)
            bus.poll(0.2)
            return payload in sink

        assert wait_until(on_b, lambda: heard(on_b, got_b, on_a, b"from host A"), 60), "data did not cross"
        # The second swarm hears its own message across the mesh, and nothing of the first.
        assert wait_until(other_b, lambda: heard(other_b, got_other, other_a, b"swarm two"), 60)
        other_b.poll(0.2)
        assert set(got_other) == {b"swarm two"} and other_alive == set(), (got_other, other_alive)
    finally:
        for bus in buses:
            bus.close()
        for p in routers:
            p.terminate()
        for p in routers:
            assert p.wait(30) == 0, p.stderr.read()
