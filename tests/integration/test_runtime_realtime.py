"""Real time over real processes: each process on its own beat, on the latest data."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from fxswarm.runtime.output import load_trajectory
from fxswarm.core.metrics import formation_errors

from support import PAPER_FAST, measured

#: The figures the paper-outcome tests bound (and print, ``MEASURED``, for their distribution).
BOUNDED = ("min_object_distance_m", "formation_error_final_m", "estimate_error_final_m", "achieved_speed")

SPEED_ALWAYS = 1.0  # real time at 100 ticks/s: holds with one swarm on the machine (not two at once)


def formation_error_at_the_end(out, last_s: float = 2.0) -> float:
    """The worst robot's median formation error over the run's last ``last_s`` s: a stall of
    less than ``last_s / 2`` at the end, which a loaded machine has, does not move it."""
    traj = load_trajectory(out)
    err = formation_errors(traj)
    return float(np.median(err[traj["t"] >= traj["t"][-1] - last_s], axis=0).max())


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
    late estimates forward to its own time (docs/design.md "Delay compensation"), so latency
    counted in ticks no longer turns into lag behind the climbing leader. Without the
    compensation the final formation error met 0.25 m in 1 run of 9 (0.43-0.62 m in the others).
    """
    swarm = launch_swarm(PAPER_FAST, clock="realtime", speed=4.0)
    summary = swarm.wait_done(timeout=300)
    detail = {k: summary.get(k) for k in ("late_ticks", "held_ticks", "achieved_speed", "sense_to_command",
                                         "formation_error_final_m", "estimate_error_final_m",
                                         "min_object_distance_m")}
    print(f"speed 4 at load average {os.getloadavg()[0]:.1f}: {detail}")
    end_err = formation_error_at_the_end(swarm.out)
    measured("speed4", load1=os.getloadavg()[0], formation_error_last_2s_m=end_err,
             **{k: summary[k] for k in BOUNDED})
    # Bounds from 26 runs on this 2-core machine at load average 9-156 (other test runs beside),
    # each at mean -/+ 4 sd: closest approach 1.77-1.97 m (mean 1.88, sd 0.058; lock-step 1.98)
    # against 1.65; estimate error 0.02-0.14 m (mean 0.058, sd 0.027) against 0.25.
    # The formation over the last 2 s (formation_error_at_the_end): 0.020-0.117 m in 7 runs at
    # load 21-35 with the compensation, 0.40-0.59 m in 4 runs at load 20-22 without it; 0.25
    # between. The last tick's error no longer told the two apart: 0.05-0.41 m with (0.41 once
    # at load 35, against 0.37 asserted then), 0.37-0.60 m without.
    # Since the world waits for a starved leader (one run had ended 1.38 m off without it), 69
    # runs three at a time at load 11-27: closest approach 1.74-1.98 m (mean 1.91, sd 0.057),
    # estimate error 0.02-0.21 m (mean 0.050, sd 0.028), formation over the last 2 s
    # 0.015-0.116 m (mean 0.035, sd 0.018). In 46 runs before it, one ended 0.266 m off: robot
    # 3 fell 0.3 m behind in the last second (its commands near zero for 0.3 s), the leader
    # heard throughout; not seen since.
    assert summary["min_object_distance_m"] >= 1.65, detail
    assert end_err <= 0.25, (end_err, detail)
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
    end_err = formation_error_at_the_end(swarm.out)
    measured("speed1", load1=os.getloadavg()[0], formation_error_last_2s_m=end_err,
             **{k: summary[k] for k in BOUNDED})
    # Bounds from 25 runs on this 2-core machine at load average 9-167: closest approach
    # 1.849-1.981 m (mean 1.958, sd 0.036) against 1.8 (mean - 4.4 sd); final formation error
    # 0.010-0.193 m (mean 0.036, sd 0.037) and estimate error 0.027-0.155 m (mean 0.051,
    # sd 0.023) against 0.25 m (mean + 5.8 and 8.6 sd).
    # The formation is judged over the run's last 2 s, not at its last tick: at load 20 (two other
    # swarms running) a 0.65 s stall in the last half second left robot 3 0.38 m off at the last
    # tick, 0.02 m off one second before; a swarm that does not hold formation is off all along.
    # Over the last 2 s: 0.017-0.048 m in 14 runs at load 15-52 (MEASURED speed1; the last tick
    # 0.018-0.38 m in the same runs); 0.25 is 5 x the worst.
    assert summary["min_object_distance_m"] >= 1.8, detail
    assert end_err <= 0.25, (end_err, detail)
    assert summary["estimate_error_final_m"] <= 0.25, detail


@pytest.mark.zenoh
def test_a_robot_whose_answers_are_lost_is_asked_again_and_the_clock_is_not_held_for_seconds(launch_swarm):
    """Robot 2's commands reach the world one time in five (a fault at the world's inbox, by each
    message's number). Ten lost in a row make it lag, and the world holds its clock; it then
    sends robot 2 its sensing again each period and robot 2 answers again, so a hold lasts a few
    periods. Without that, robot 2 waited for fresh sensing and the world for robot 2: every
    hold ran out its whole limit (1 s), tick after tick: in one run the 3 s run took 17 s
    (achieved speed 0.18, against 0.95 now), the machine idle meanwhile."""
    swarm = launch_swarm(PAPER_FAST, duration=3.0, clock="realtime", speed=1.0, tick_timeout=1.0,
                         **{"faults.seed": 7,
                            "faults.links": [{"link": "agent:2->world", "kinds": ["command"], "drop": 0.8}]})
    summary = swarm.wait_done(timeout=180)
    detail = {k: summary.get(k) for k in ("held_ticks", "sensing_sent_again", "achieved_speed", "wall_s")}
    print(detail)
    measured("lost-answers", load1=os.getloadavg()[0], achieved_speed=summary["achieved_speed"],
             held_ticks=summary["held_ticks"])
    assert summary["complete"] and summary["ticks"] == 300, detail
    assert summary["faults"]["links"]["agent:2->world/command"]["dropped"] > 100, summary["faults"]["links"]
    assert summary["sensing_sent_again"] > 0 and summary["held_ticks"] > 0, detail  # it lagged, and was asked
    # Not held for seconds: the clock's holds, in pacer periods (10 ms), 17-41 in 17 runs at load
    # average 8-50, 291 once at 85; without the asking again each hold ran its 1 s limit, 14 s in
    # all (about 1400). The speed reached is the machine's more than the code's (0.20-0.95 in those
    # runs, 0.20 at load 50 with 22 held): printed (MEASURED), not asserted.
    assert summary["held_ticks"] < 700, detail


@pytest.mark.zenoh
def test_the_world_waits_for_a_leader_starved_of_cpu_so_its_states_never_go_stale(launch_swarm):
    """The leader's process gets no CPU for 1.5 s (SIGSTOP by the test, not by the plan: the
    plan's freeze is an experiment, not waited for). Its states are stamped with the world's
    time as it last heard it, so a world that ran on would leave them older than the robots'
    staleness limit (0.5 s): robots 1 and 4 would drop the leader and the swarm fly on without
    its anchor, as in a loaded run at speed 4 that ended 1.38 m off. The world holds its clock
    for it instead, as for a starved robot, and says so (``held_for``)."""
    swarm = launch_swarm(PAPER_FAST, duration=3.0, clock="realtime", speed=1.0)
    swarm.wait_for_sim_time(1.0, timeout=60)
    swarm.freeze("leader")
    try:
        frozen_at = swarm.sim_time()
        starved = time.monotonic() + 1.5  # the fault's length, not a wait for an event
        while time.monotonic() < starved:
            swarm.pump()
        ran_on = swarm.sim_time() - frozen_at
    finally:
        swarm.thaw("leader")
    summary = swarm.wait_done(timeout=120)
    no_leader = summary["faults"]["degraded_ticks"]["no_leader"]
    detail = {"ran_on_s": ran_on, "held_for": summary.get("held_for"), "no_leader": no_leader,
              "achieved_speed": summary["achieved_speed"]}
    print(detail)
    measured("starved-leader", load1=os.getloadavg()[0], ran_on_s=ran_on, no_leader=sum(no_leader.values()),
             held_for_leader=summary["held_for"].get("leader", 0))
    assert summary["complete"] and summary["ticks"] == 300, detail
    # Held: the world went on max_lag ticks and a tick per hold limit (1 s) past the leader's
    # last state: 0.05-0.12 s in 20 runs at load 9-21 (two speed-4 swarms and a busy loop beside).
    # Without the wait it ran on 1.51 s (quiet). 0.5 s, the staleness limit, stands between.
    assert ran_on < 0.5, detail
    assert summary["held_for"].get("leader", 0) > 0, detail
    # The pinned robots (1 and 4) hardly ever held a leader's state older than 0.5 s: 1-6 ticks
    # in all in the same 20 runs. Without the wait, 104 ticks each (208).
    assert sum(no_leader.values()) < 20, detail


@pytest.mark.zenoh
def test_a_robot_a_partition_cuts_off_from_the_world_is_not_waited_for(launch_swarm):
    """Robot 3's commands to the world are cut from 1.0 to 1.5 s. That silence is the
    experiment, not a starved robot: the world's clock goes on through it (robot 3 held on its
    last command), as lock-step does not wait for a message the plan withholds. Waiting for it
    held the clock a second a tick: in one run the 3 s run took 43 s (achieved speed 0.07)."""
    swarm = launch_swarm(PAPER_FAST, duration=3.0, clock="realtime", speed=1.0, tick_timeout=1.0,
                         **{"faults.seed": 7, "faults.partitions": [
                             {"start": 1.0, "end": 1.5, "links": ["agent:3->world"], "kinds": ["command"]}]})
    summary = swarm.wait_done(timeout=180)
    detail = {k: summary.get(k) for k in ("held_ticks", "sensing_sent_again", "achieved_speed", "wall_s")}
    print(detail)
    dropped = summary["faults"]["links"]["agent:3->world/command"]["dropped"]
    measured("partition", load1=os.getloadavg()[0], achieved_speed=summary["achieved_speed"],
             held_ticks=summary["held_ticks"], wall_s=summary["wall_s"], dropped=dropped)
    assert summary["complete"] and summary["ticks"] == 300, detail
    # The cut happened: without it none is dropped. How many (robot 3 answers each of the cut's
    # 50 ticks once when it keeps up, 34 at load 25, fewer when starved of CPU) is the machine's
    # figure, printed, not a bound: one observation cannot place one.
    assert dropped > 0, summary["faults"]["links"]
    # Waiting for robot 3 holds each of the cut's 50 ticks for the 1 s limit, wall time on any
    # machine: 53 s or more (43 s measured, above). Not waiting: 3.0-7.0 s in 36 runs at load
    # average 8-56 (20 in a row at 12-30: 3.0-3.6 s), 9.7 s once more at 55 (speed reached
    # 0.31-1.00, held 0-616 periods: the machine's figures more than the code's, printed, not
    # asserted). 30 s stands between.
    assert summary["wall_s"] < 30.0, detail
