"""Fixtures the tests share (the project's own harness, ``fxswarm.testing``, is a plugin)."""

from __future__ import annotations

import pytest

from fxswarm.runtime.launcher import free_port
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions


@pytest.fixture
def router():
    """A Zenoh router (a session in this process) on a free port; its endpoint."""
    port = free_port()
    bus = ZenohBus("unused", ZenohOptions("router", listen=(f"tcp/127.0.0.1:{port}",), multicast=False))
    yield f"tcp/127.0.0.1:{port}"
    bus.close()


@pytest.fixture
def zenoh_client(router):
    """``zenoh_client(swarm)``: a client session of :func:`router`'s, closed at teardown."""
    opened: list[ZenohBus] = []

    def open_client(swarm: str) -> ZenohBus:
        bus = ZenohBus(swarm, ZenohOptions("client", connect=(router,), multicast=False))
        opened.append(bus)
        return bus

    yield open_client
    for bus in opened:
        bus.close()
