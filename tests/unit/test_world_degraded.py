"""summary.json's ``degraded`` and ``router_outages`` (issue 29): what the world could not hear, and
when this process had lost every router, counted where they happen."""

from __future__ import annotations

import uuid
from types import SimpleNamespace

import numpy as np
import zenoh

from fxswarm.core.scenario import load
from fxswarm.runtime.connectivity import Connectivity
from fxswarm.world.node import WorldNode

from support import PAPER_FAST


def advance(world: WorldNode, heard: set[int], ticks: int) -> None:
    for _ in range(ticks):
        for r in heard:
            world.take_command(SimpleNamespace(robot=r, v=np.zeros(3), ph=np.zeros(3), avoid_active=False, flags=0,
                                               link_age=(0,) * world.in_degree[r - 1],
                                               link_drops=(0,) * world.in_degree[r - 1], tick=world.tick))
        world.advance(world.sc.dt)


def test_a_world_counts_the_ticks_it_held_robots_it_could_not_hear_and_whether_it_heard_none():
    world = WorldNode(load(PAPER_FAST))  # silent_hold 0.5 s = 50 ticks
    everyone = {r.id for r in world.sc.robots}
    advance(world, everyone, 20)
    assert world.degraded() == {"ticks": 0, "robots": []} and world.unheard_since is None
    advance(world, everyone - {2}, 60)  # robot 2 silent for 60 ticks: held at zero after 50
    assert world.degraded() == {"ticks": 10, "robots": [2]} and world.unheard_since is None
    advance(world, everyone, 5)
    advance(world, set(), 70)  # nobody heard (its router gone): all held after 50 ticks
    assert world.degraded() == {"ticks": 30, "robots": [1, 2, 3, 4, 5, 6]}
    assert world.unheard_since == 20 + 60 + 5 + 50
    advance(world, {3}, 1)  # one robot heard again: not alone any more
    assert world.unheard_since is None


def test_a_finished_run_flown_alone_exits_1_but_0_with_finished_ok_and_a_cut_short_one_never_0(capsys):
    """`fxswarm stack` runs the world with --finished-ok: Docker Swarm (restart_policy on-failure)
    restarts a task that exits non-zero, and a run that reached its end must not start over."""
    import dataclasses

    from fxswarm.world.process import ALONE_EXIT, exit_status

    world = WorldNode(dataclasses.replace(load(PAPER_FAST), duration=1.0))
    everyone = {r.id for r in world.sc.robots}
    advance(world, everyone, 40)
    assert not world.done
    assert exit_status(world, "world lost", [], finished_ok=True) == 1  # cut short: restarted
    assert exit_status(world, "SIGTERM", [], finished_ok=True) == 128 + 15
    advance(world, set(), 60)  # nobody heard to the end: flown alone
    assert world.done and world.unheard_since is not None
    capsys.readouterr()
    assert exit_status(world, "done", []) == ALONE_EXIT == 1
    assert "the run is not a success; exit status 1" in capsys.readouterr().err
    assert exit_status(world, "done", [], finished_ok=True) == 0
    assert "exit status 0 (--finished-ok: the run reached its end)" in capsys.readouterr().err
    healthy = WorldNode(dataclasses.replace(load(PAPER_FAST), duration=0.5))
    advance(healthy, everyone, 50)
    assert healthy.done and exit_status(healthy, "done", []) == 0


class FakeInfo:
    def __init__(self) -> None:
        self.handler = None

    def declare_transport_events_listener(self, handler, history):
        self.handler = handler
        return SimpleNamespace(undeclare=lambda: None)


def event(kind, zid: str, what: str = "router"):
    return SimpleNamespace(kind=kind, transport=SimpleNamespace(is_multicast=False, zid=zid, whatami=what))


def test_losing_every_router_is_said_once_and_its_return_too_with_the_ticks_in_between():
    info, said, now = FakeInfo(), [], [0.0, 0]
    watch = Connectivity(SimpleNamespace(info=info), "fxswarm world", now=lambda: tuple(now), say=said.append)
    put, delete = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE
    info.handler(event(put, "a"))
    info.handler(event(put, "b"))  # two routers
    now[:] = [1.0, 100]
    info.handler(event(delete, "a"))
    assert not watch.lost and not said  # one router left: nothing to say
    info.handler(event(delete, "b"))
    assert watch.lost and len(said) == 1 and "lost every router at t = 1.00 s" in said[0]
    now[:] = [1.5, 150]
    assert watch.report() == [{"start": 1.0, "end": None, "ticks": 50}]
    now[:] = [3.0, 300]
    info.handler(event(put, "c"))  # a router again (restarted: a new id)
    assert not watch.lost and "reached the swarm again at t = 3.00 s" in said[1] and "200 ticks" in said[1]
    assert watch.report() == [{"start": 1.0, "end": 3.0, "ticks": 200}]
    watch.close()
    info.handler(event(delete, "c"))  # the session closing is no outage
    assert len(said) == 2 and len(watch.report()) == 1


def test_a_mesh_peer_that_never_had_a_link_is_not_lost():
    info, said = FakeInfo(), []
    watch = Connectivity(SimpleNamespace(info=info), "fxswarm agent 1", say=said.append)
    info.handler(event(zenoh.SampleKind.DELETE, uuid.uuid4().hex, "peer"))
    assert not said and not watch.lost and watch.report() == []
