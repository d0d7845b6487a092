"""Who died during a run, as ``fxswarm attach`` tells it from liveliness and the world's ticks."""

from __future__ import annotations

from fxswarm.core.scenario import load
from fxswarm.launch.attach import Observer
from support import PAPER_FAST


def observer_at(tick: int) -> Observer:
    obs = Observer(load(PAPER_FAST))
    obs.last_tick = tick
    return obs


def test_leaving_at_the_end_is_not_a_death_even_before_the_last_states_arrive():
    obs = observer_at(100)
    for i in (1, 2):
        obs.on_alive(f"agent/{i}", True)
    obs.last_tick = obs.sc.ticks - 3  # the world's last states are still on their way
    obs.on_alive("agent/1", False)
    obs.on_alive("agent/2", False)
    obs.last_tick = obs.sc.ticks - 1
    assert obs.deaths() == {}


def test_a_killed_process_counts_whether_or_not_it_comes_back():
    obs = observer_at(10)
    for i in (3, 4):
        obs.on_alive(f"agent/{i}", True)
    obs.on_alive("agent/3", False)  # killed at tick 10, replaced
    obs.on_alive("agent/4", False)  # killed at tick 10, never back
    obs.last_tick = 300
    obs.on_alive("agent/3", True)
    obs.last_tick = obs.sc.ticks - 2
    obs.on_alive("agent/3", False)  # the replacement leaves at the end: not a second death
    obs.last_tick = obs.sc.ticks - 1
    assert obs.deaths() == {"agent/3": 1, "agent/4": 1}
    assert obs.summary(1.0)["restarts"] == {"agent/3": [1, 1], "agent/4": [1, 0]}


def test_tokens_that_go_and_come_back_with_our_own_link_are_nobodys_death():
    """attach's own router blinked (issue 29): every token went with it and came back; a process
    that really died meanwhile still counts."""
    cut = {"now": False}
    obs = Observer(load(PAPER_FAST), cut_around=lambda _when: cut["now"])
    obs.last_tick = 10
    for name in ("agent/1", "agent/2", "world/0"):
        obs.on_alive(name, True)
    obs.on_alive("agent/2", False)  # killed, before our link went
    cut["now"] = True
    for name in ("agent/1", "world/0"):
        obs.on_alive(name, False)  # handled a little before the transport's own event, even
    obs.last_tick = 500
    for name in ("agent/1", "world/0"):
        obs.on_alive(name, True)
    cut["now"] = False
    obs.last_tick = obs.sc.ticks - 1
    assert obs.deaths() == {"agent/2": 1}
    assert obs.observed()["restarts"] == {"agent/2": [1, 0]}


def test_leaving_at_the_end_behind_a_lagging_live_stream_is_not_a_death():
    """Loaded, the live stream lags (its states seconds of simulation old) and the departures at
    the end can overtake the world's run/over token: they are still the run's end (a Swarm stack
    run once counted every process dead so). A process killed mid-run still counts."""
    now = {"s": 0.0}
    obs = Observer(load(PAPER_FAST), clock=lambda: now["s"])
    for i in (1, 2, 3):
        obs.on_alive(f"agent/{i}", True)
    obs.last_tick = 400
    now["s"] = 5.0
    obs.on_alive("agent/3", False)  # killed, never back
    end = obs.sc.ticks
    obs.last_tick = end - 300  # the stream 3 s of simulation behind the world
    now["s"] = 20.0
    obs.on_alive("agent/1", False)
    obs.on_alive("agent/2", False)
    now["s"] = 20.08
    obs.on_run_over("run/over", True)
    obs.last_tick = end - 1  # the stream catches up
    assert obs.deaths() == {"agent/3": 1}
    assert obs.observed()["restarts"] == {"agent/3": [1, 0]}
