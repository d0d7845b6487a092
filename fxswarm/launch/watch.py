"""The launcher's own Zenoh session: who is alive (liveliness tokens) and the world's latest state."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from fxswarm.core import bus as topics
from fxswarm.core.messages import WireError, WorldState, decode
from fxswarm.runtime.zenoh_bus import ConnectError, ZenohBus, ZenohOptions, check_sender


class StartError(RuntimeError):
    """The swarm did not come up; the message says who is missing or who died."""


class Watch:
    """What the launcher hears; :meth:`open` joins, :meth:`pump` lets the callbacks run."""

    def __init__(self, state_listener: Callable[[WorldState], object] | None = None) -> None:
        self.alive: set[str] = set()  # tokens up: "agent/3", "router/0", "router/link-..."
        self.bus: ZenohBus | None = None
        self.state_listener = state_listener  # each valid world state heard (`run --ros2`)
        self._state_bytes: bytes | None = None  # the latest world/state heard, decoded only when asked
        self._state: WorldState | None = None

    def open(self, swarm: str, options: ZenohOptions, wait_ms: int, on_wait: Callable[[], None]) -> None:
        """Join ``swarm``. A client (routed) waits up to ``wait_ms`` for the router just started,
        which takes a moment to come up or may die: ``on_wait`` (between two attempts) may raise
        :class:`StartError` to say why rather than wait out the timeout."""
        try:
            self.bus = ZenohBus(swarm, replace(options, connect_timeout_ms=wait_ms), validate=True,
                                who="fxswarm run", on_wait=on_wait)
        except ConnectError as exc:
            raise StartError(str(exc)) from None
        self.bus.watch_alive("**", self._on_alive)
        self.bus.watch_router_links(self._on_alive)  # zenohd declares no token: a link to it tells
        self.bus.subscribe(topics.WORLD_STATE, self._on_state, raw=True)

    def pump(self, timeout: float) -> None:
        if self.bus is not None:
            self.bus.poll(timeout)

    def close(self) -> None:
        if self.bus is not None:
            self.bus.close()
            self.bus = None

    def _on_alive(self, name: str, up: bool) -> None:
        (self.alive.add if up else self.alive.discard)(name)

    def _on_state(self, topic: str, payload: bytes) -> None:
        self._state_bytes = payload  # decoded only when read: most states are never looked at
        if self.state_listener is not None:
            state = self.state
            if state is not None:
                self.state_listener(state)

    @property
    def state(self) -> WorldState | None:
        """The latest valid world state heard (None before the first). An invalid one (a
        stranger's, or garbage) is counted and leaves the last valid one in place."""
        payload, self._state_bytes = self._state_bytes, None
        if payload is not None:
            try:
                msg = decode(payload)
                check_sender(topics.WORLD_STATE, msg)
                self._state = msg
            except WireError:
                self.bus.counters.invalid += 1
        return self._state
