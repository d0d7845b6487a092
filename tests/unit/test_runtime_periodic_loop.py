"""The real-time loop of a process shell with a fake bus: when it acts, and that its timer holds."""

from __future__ import annotations


def test_periodic_loop_acts_on_fresh_data_inside_the_delivery_and_keeps_its_timer():
    """Real time: an early act happens where the message is delivered (on Zenoh's callback thread
    under ``poll(stay=True)``), not after the poll returns; the timer then waits ``patience``."""
    import time
    from types import SimpleNamespace

    from fxswarm.core.pacing import Pacer
    from fxswarm.runtime.process import run_periodic_loop

    period = 0.05
    acts: list[tuple[str, float]] = []
    fresh = {"sense": False}

    class Bus:
        polls = 0

        def poll(self, timeout, stay=False):
            self.polls += 1
            if self.polls == 2:  # fresh sensing lands during the second poll
                assert stay
                fresh["sense"] = True
                proc.deliver()
                acts.append(("poll returns", time.monotonic()))
            elif timeout:
                time.sleep(timeout)
            return 0

    def deliver():
        if proc.after_deliver is not None:
            proc.after_deliver()

    def act():
        acts.append(("act", time.monotonic()))
        fresh["sense"] = False
        if len([a for a in acts if a[0] == "act"]) == 3:
            proc.stopping = True

    proc = SimpleNamespace(bus=Bus(), node=object(), gone=set(), stopping=False, after_deliver=None,
                           deliver=deliver, publish=lambda out: None, check_parent=lambda: None,
                           exit_with_world=lambda: None)
    run_periodic_loop(proc, Pacer(period, time.monotonic, patience=1.5), act, act_early=lambda: fresh["sense"])
    names = [n for n, _ in acts]
    assert names[:3] == ["act", "act", "poll returns"], acts  # timer at start, then early inside the poll
    early, timer = acts[1][1], acts[3][1]
    assert names[3] == "act" and timer - early >= 1.5 * period - 0.005, acts  # the timer waited patience


def test_a_world_that_paces_itself_ticks_once_per_period():
    """The real-time world's ``tick()`` records its act on the pacer itself (act or hold): the loop
    must not record it again, or every deadline moves one more period away and the world runs at
    half speed with no tick counted late."""
    from types import SimpleNamespace

    from fxswarm.core.scenario import load
    from fxswarm.runtime.process import run_periodic_loop
    from fxswarm.world.node import RealTimeWorld, WorldNode

    from support import PAPER_FAST

    sc = load(PAPER_FAST)
    now = [0.0]
    clock = lambda: now[0]  # noqa: E731 - a fake clock the fake bus moves
    world = RealTimeWorld(WorldNode(sc, record=False), sc.dt, clock)

    class Bus:
        def poll(self, timeout, stay=False):
            now[0] += max(timeout, 0.0)  # nothing arrives: the wait passes in full
            return 0

    def tick():
        world.tick()
        if world.inner.tick >= 100:
            proc.stopping = True

    proc = SimpleNamespace(bus=Bus(), node=world, gone=set(), stopping=False, after_deliver=None,
                           publish=lambda out: None, check_parent=lambda: None, exit_with_world=lambda: None)
    world.start()
    run_periodic_loop(proc, world.pacer, tick, act_keeps_time=True)
    report = world.report()
    assert world.inner.tick == 100 and report["late_ticks"] == 0 and report["held_ticks"] == 0
    assert abs(report["achieved_speed"] - 1.0) < 1e-6, report
