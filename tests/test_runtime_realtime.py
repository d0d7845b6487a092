"""Real time over real processes: each process on its own beat, on the latest data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from fxswarm.runtime.output import load_trajectory
from fxswarm.core.metrics import formation_errors

SPEED_ALWAYS = 1.0  # real time at 100 ticks/s: holds with one swarm on the machine (not two at once)
PAPER_FAST = Path(__file__).resolve().parents[1] / "configs" / "paper-fast.toml"


@pytest.mark.zenoh
def test_realtime_swarm_flies_toward_formation_and_measures_its_latency(launch_swarm):
    swarm = launch_swarm(PAPER_FAST, duration=3.0, clock="realtime", speed=1.0)
    summary = swarm.wait_done(timeout=120)
    assert summary["complete"] and summary["clock"] == "realtime" and summary["ticks"] == 300
    err = formation_errors(load_trajectory(swarm.out)).max(axis=1)
    assert err[-1] < 0.6 * err[0], (err[0], err[-1])  # converging (6.4 m -> about 1 m in the sim)
    lat = summary["sense_to_command"]
    assert lat["n"] > 0 and 0 < lat["p50_ms"] <= lat["p99_ms"] <= lat["max_ms"]
    procs = summary["processes"]
    for name, c in procs.items():
        assert c["invalid"] == 0, name
        if name.startswith("agent"):
            assert c["sent"] > 100 and c["received"] > 100, (name, c)
    assert procs["leader-0"]["sent"] > 100  # on its own beat: no answer to a clock needed


@pytest.mark.zenoh
@pytest.mark.slow
def test_paper_fast_in_real_time_at_speed_4_meets_the_paper_outcome(launch_swarm):
    """The issue's must-show, asserted on every machine.

    The machine need not keep up with 400 ticks/s: the world slows its clock rather than
    integrate on stale commands (``achieved_speed``), and each robot carries its neighbours'
    late estimates forward to its own time (delay compensation, docs/DESIGN.md), so latency
    counted in ticks no longer turns into lag behind the climbing leader. Without the
    compensation the final formation error met 0.25 m in 1 run of 9 (0.43-0.62 m in the others).
    """
    swarm = launch_swarm(PAPER_FAST, clock="realtime", speed=4.0)
    summary = swarm.wait_done(timeout=300)
    detail = {k: summary.get(k) for k in ("late_ticks", "held_ticks", "achieved_speed", "sense_to_command",
                                         "formation_error_final_m", "estimate_error_final_m",
                                         "min_object_distance_m")}
    print(f"speed 4 at load average {os.getloadavg()[0]:.1f}: {detail}")
    assert summary["min_object_distance_m"] >= 1.8, detail
    assert summary["formation_error_final_m"] <= 0.25, detail
    assert summary["estimate_error_final_m"] <= 0.25, detail


@pytest.mark.zenoh
@pytest.mark.slow
def test_paper_fast_in_real_time_meets_the_real_time_outcome_on_a_loaded_machine(launch_swarm):
    """Asserted on every machine: at 100 ticks/s (wall time) this 2-core machine keeps up even when loaded,
    where at speed 4 it slows the world's clock."""
    swarm = launch_swarm(PAPER_FAST, clock="realtime", speed=SPEED_ALWAYS)
    summary = swarm.wait_done(timeout=300)
    detail = {k: summary.get(k) for k in ("late_ticks", "held_ticks", "achieved_speed", "sense_to_command",
                                         "formation_error_final_m", "estimate_error_final_m",
                                         "min_object_distance_m")}
    assert summary["min_object_distance_m"] >= 1.8, detail
    assert summary["formation_error_final_m"] <= 0.25, detail
    assert summary["estimate_error_final_m"] <= 0.25, detail


def test_periodic_loop_acts_on_fresh_data_inside_the_delivery_and_keeps_its_timer():
    """Real time: an early act happens where the message is delivered (on Zenoh's callback thread
    under ``poll(stay=True)``), not after the poll returns; the timer then waits ``patience``."""
    import time
    from types import SimpleNamespace

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
    run_periodic_loop(proc, period, act, act_early=lambda: fresh["sense"], patience=1.5)
    names = [n for n, _ in acts]
    assert names[:3] == ["act", "act", "poll returns"], acts  # timer at start, then early inside the poll
    early, timer = acts[1][1], acts[3][1]
    assert names[3] == "act" and timer - early >= 1.5 * period - 0.005, acts  # the timer waited patience
