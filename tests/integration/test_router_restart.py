"""A swarm outlives its router: killed mid-run, started again by the launcher, or one of two
meshed routers killed for good. Real processes, real Zenoh sessions, every process a client.

Lock-step: what was put while the router was down is lost; the world holds the tick while the
processes lost with the router are away, then asks again for it (``world/again``), and each
says again what it said for that tick, so the run is bit-identical to ``fxswarm sim``.
"""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

from fxswarm.core.metrics import formation_errors
from fxswarm.faults.plan import DegradedLimits
from fxswarm.runtime.output import load_trajectory

pytestmark = [pytest.mark.zenoh, pytest.mark.timeout(600)]


def kill_router_unplanned(swarm, name: str = "router") -> int:
    """SIGKILL the router behind the launcher's back (a crash, not a planned stop); return its pid."""
    pid = swarm.pid(name)
    os.kill(pid, signal.SIGKILL)
    return pid


def wait_restarted(swarm, name: str, old_pid: int) -> None:
    """Pump until the launcher has started the router again and its token is back."""
    swarm.wait_for(lambda: swarm.pid(name) != old_pid, f"{name} started again", timeout=30)
    swarm.wait_alive(name, timeout=30)


def asked_again(swarm) -> int:
    return json.loads((swarm.out / "processes" / "world-0.json").read_text())["asked_again"]


def keys_for(tmp_path, secure: bool):
    """A keys folder for paper-fast (secure mode), or None."""
    if not secure:
        return None
    from fxswarm.core.scenario import load
    from fxswarm.security.keys import write_keys

    keys = tmp_path / "keys"
    write_keys(keys, load("configs/paper-fast.toml"))
    return keys


@pytest.mark.parametrize("secure", [False, True], ids=["plain", "secure"])
def test_lockstep_run_survives_a_router_restart_bit_identical(launch_swarm, secure, tmp_path):
    # Secure: started again with the same keys and rules (the same command).
    swarm = launch_swarm(topology="routed", duration=6.0, secure=keys_for(tmp_path, secure))
    swarm.wait_for_sim_time(1.0, timeout=120)
    old = kill_router_unplanned(swarm)
    wait_restarted(swarm, "router", old)
    assert swarm.swarm.router_restarts == 1
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] is True and summary["ticks"] == 600, summary
    assert summary["missed_ticks"] == 0, summary
    assert asked_again(swarm) >= 1  # the outage was seen and what it swallowed asked for again
    swarm.assert_matches_sim()


@pytest.mark.parametrize("secure", [False, True], ids=["plain", "secure"])
def test_a_router_without_a_token_restarted_is_seen_by_each_process_own_link(launch_swarm, secure, tmp_path,
                                                                              monkeypatch):
    """zenohd declares no alive/router token: a stand-in started as zenohd is (`-c FILE`, the
    configuration fxswarm run writes for it, keys and rules included) restarted mid-run; each
    process sees the outage by its own link to the router, and the run equals fxswarm sim."""
    import sys

    if not os.environ.get("FXSWARM_ZENOHD"):
        monkeypatch.setenv("FXSWARM_ZENOHD", f"{sys.executable} tests/integration/tokenless_router.py")
    swarm = launch_swarm(topology="routed", duration=6.0, secure=keys_for(tmp_path, secure))
    assert (swarm.out / "router.zenohd.json5").exists()
    swarm.wait_for_sim_time(1.0, timeout=120)
    old = kill_router_unplanned(swarm)
    wait_restarted(swarm, "router", old)
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] is True and summary["missed_ticks"] == 0, summary
    assert asked_again(swarm) >= 1
    swarm.assert_matches_sim()


@pytest.mark.skipif(bool(os.environ.get("FXSWARM_ZENOHD")),
                    reason="zenohd declares no alive/router token: a process on the surviving router cannot tell "
                           "its peers' router went from their deaths (docs/routers.md)")
@pytest.mark.parametrize("secure", [False, True], ids=["plain", "secure"])
def test_two_routers_one_killed_for_good_the_run_completes_on_the_other(launch_swarm, secure, tmp_path):
    # Secure: the routers mesh over mutual TLS, each trusting the other's `router` certificate.
    swarm = launch_swarm(topology="routed", duration=6.0, routers=2, secure=keys_for(tmp_path, secure))
    swarm.wait_for_sim_time(1.0, timeout=120)
    # Planned: the launcher does not start it again. Half the processes were its clients.
    swarm.kill("router")
    summary = swarm.wait_done(timeout=300)
    assert swarm.swarm.router_restarts == 0
    assert summary["complete"] is True and summary["missed_ticks"] == 0, summary
    assert asked_again(swarm) >= 1
    swarm.assert_matches_sim()


def test_realtime_run_goes_on_through_a_router_restart_and_recovers_formation(launch_swarm):
    # paper-fast whole, at twice real time (a 40 s flight in 20 s); the router killed at 10 s.
    swarm = launch_swarm(topology="routed", clock="realtime", speed=2.0)
    swarm.wait_for_sim_time(10.0, timeout=120)
    old = kill_router_unplanned(swarm)
    wait_restarted(swarm, "router", old)
    summary = swarm.wait_done(timeout=300)
    assert summary["complete"] is True, summary
    err = formation_errors(load_trajectory(swarm.out)).max(axis=1)
    t = np.arange(len(err)) * swarm.scenario.dt
    from support import measured

    measured("router_restart_realtime", load1=os.getloadavg()[0], before_m=err[(t > 8.0) & (t < 10.0)].max(),
             outage_max_m=err[(t > 10.0) & (t < 20.0)].max(), final_m=summary["formation_error_final_m"],
             last_2s_m=err[t > t[-1] - 2.0].max(), outage_ticks=sum(o["ticks"] for o in summary["router_outages"]),
             held=summary["degraded"]["ticks"])
    # The world reports the outage: one, after the kill, ended (the router came back), ticks run
    # meanwhile. Planted (no router kill): no outage, and this fails.
    (outage,) = summary["router_outages"]
    assert outage["start"] > 9.0 and outage["end"] is not None and outage["end"] > outage["start"], outage
    assert outage["ticks"] > 0, outage
    # It showed in the flight: the world held each robot it could not hear at zero, from
    # silent_hold (0.5 s: 50 ticks) into the outage until it heard the robot again, and none
    # while the router was up. Measured (40 runs of issue 40 at load average 9-36, `fxswarm
    # router`): held the outage's ticks less 33-50, over outages of 137-1328 ticks; a world that
    # holds none fails here (less 100 allowed: twice silent_hold). zenohd came back within 20
    # ticks, before any robot was held. A robot may reach the new router after the world does
    # (Zenoh's reconnection retries): once robots 1 and 3 came back 1 s after the others, held
    # 130 ticks past the world's outage. So each robot's hold is judged by itself: one stretch,
    # from silent_hold into the outage (0.40-0.51 s in 21 runs at load 4-18) to the world's having
    # the router again or later (-0.01 to +0.11 s; 1.3 s for those two, 1.6 s once for five);
    # 22 consecutive runs at load 5-17 passed.
    # (The error's growth is no such check: without an outage the error between 10 and 20 s still
    # exceeded the error before 10 s, 1.73 m against 1.58 m, as paper-fast's obstacles come.)
    held, hold_ticks = summary["degraded"]["ticks"], round(DegradedLimits.silent_hold / swarm.scenario.dt)
    assert held >= outage["ticks"] - 2 * hold_ticks, (held, outage)
    traj = load_trajectory(swarm.out)
    for r in range(swarm.scenario.n):
        still = np.all(traj["v"][:, r] == 0.0, axis=1)
        first = int(np.argmin(still))  # the first tick it moved: before, no command had come yet
        zero = np.flatnonzero(still[first:]) + first
        if not len(zero):  # never held: only through an outage shorter than silent_hold (zenohd's)
            assert outage["ticks"] <= hold_ticks, (r + 1, outage)
            continue
        stretch = (r + 1, traj["t"][zero[0]], traj["t"][zero[-1]], len(zero))
        assert zero[-1] - zero[0] + 1 == len(zero), (stretch, outage)
        assert traj["t"][zero[0]] >= outage["start"] + DegradedLimits.silent_hold - 0.2, (stretch, outage)
        assert traj["t"][zero[-1]] >= outage["end"] - 0.1, (stretch, outage)
    # And the formation recovered: the final error 0.015-0.226 m in 40 runs at load average 9-36,
    # and at most 0.232 m over the last 2 s (the law's chatter under load: the last tick samples
    # it). 0.5 m is 2.2x the worst; a swarm that does not recover stays meters off (3.0-31.6 m
    # during those outages).
    assert summary["formation_error_final_m"] <= 0.5, summary["formation_error_final_m"]


@pytest.mark.parametrize("protected", [True, False], ids=["secure", "rules-off"])
def test_secure_failover_gets_nothing_through_a_rogue_router(tmp_path, protected):
    """A process fails over to the next router it lists when its own is lost. A rogue listening
    there with a stolen robot's certificate (same CA, not the ``router``'s) gets a TLS link, but
    nothing through it: the process trusts only the ``router`` certificate to forward
    (fxswarm.runtime.tls.session_rules), so the rogue hears none of its puts and its forged
    commands never land. With those rules off the same rogue hears and forges freely."""
    import subprocess
    import sys
    import threading
    import time

    import zenoh

    from fxswarm.core.scenario import load
    from fxswarm.launch.launcher import free_port
    from fxswarm.runtime.tls import checked
    from fxswarm.runtime.zenoh_bus import ZenohOptions, open_session
    from fxswarm.security.keys import write_keys

    from support import PAPER_FAST, fxswarm_command

    keys = tmp_path / "keys"
    write_keys(keys, load(PAPER_FAST))
    swarm = f"rogue-{os.getpid()}"
    real_ep, rogue_ep = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    real = subprocess.Popen(fxswarm_command("router", "--secure", keys, "--listen", real_ep, "--swarm", swarm),
                            stderr=subprocess.DEVNULL)
    stolen = checked(keys, "agent-2").zenoh_tls(listen=True)
    rogue = subprocess.Popen([sys.executable, "tests/integration/rogue_router.py", "--listen", rogue_ep,
                              "--swarm", swarm, "--tls", json.dumps(stolen)], stdout=subprocess.PIPE, text=True)
    session = None
    said: list[str] = []  # the rogue's lines after "rogue up": "heard" at its first sample, its report at the end

    def read_rogue() -> None:
        for line in rogue.stdout:
            said.append(line.strip())

    reader = threading.Thread(target=read_rogue, daemon=True)
    try:
        assert rogue.stdout.readline().strip() == "rogue up"
        reader.start()
        options = ZenohOptions("client", (real_ep, rogue_ep), (), False, connect_timeout_ms=60_000,
                               tls=checked(keys, "world"))
        if protected:
            session = open_session(options, "test")
        else:  # the same client with its own rules off: it trusts whoever answers at a router's address
            conf = options.config()
            conf.insert_json5("access_control", '{"enabled": false}')
            session = zenoh.open(conf)
        landed: list[bytes] = []
        session.declare_subscriber(f"fxswarm/{swarm}/agent/1/cmd", lambda s: landed.append(s.payload.to_bytes()))

        def router_now():
            return [str(z) for z in session.info.routers_zid()]

        first = router_now()
        assert len(first) == 1, first
        real.kill()
        real.wait()
        end = time.monotonic() + 30
        while router_now() in ([], first):  # failed over (a TLS link to the rogue) or not yet
            assert time.monotonic() < end, "the client never linked to the next router it lists"
            time.sleep(0.05)
        # Put what the world puts, and watch for forged commands: the rogue forges 4 a second. With
        # the rules off, until a forgery has landed and the rogue has heard a put (stopping at the
        # first landing alone once left it nothing heard: its forgery can come before it hears).
        linked = time.monotonic()
        end = linked + (4.0 if protected else 30.0)
        while time.monotonic() < end and (protected or not (landed and "heard" in said)):
            session.put(f"fxswarm/{swarm}/world/sense/1", b"not for a rogue")
            time.sleep(0.05)
    finally:
        if session is not None:
            session.close()
        real.kill()
        rogue.terminate()
        rogue.wait(10)
        real.wait(10)
        if reader.is_alive():
            reader.join(10)
    report = json.loads(said[-1])
    if protected:  # it forged all along the 4 s after the failover, and none landed; it heard none of the client's puts
        during = [t for t in report["forged_at"] if linked <= t <= end]
        assert len(during) >= 4 and landed == [] and report["heard"] == 0, (len(during), len(landed), report)
    else:
        assert landed and report["heard"] > 0, (len(landed), report)


def test_fxswarm_run_restarts_a_crashed_router_says_so_and_exits_0(tmp_path):
    """The command a user runs: the router SIGKILLed under `fxswarm run` (routed) is started again
    on its port, the console says so, the run completes and the launcher exits 0."""
    import subprocess

    from fxswarm.testing import scenario_with

    from support import PAPER_FAST, fxswarm_command
    from test_runtime_shutdown import children_of, wait_for_line

    config = scenario_with(PAPER_FAST, tmp_path, duration=6.0)
    launcher = subprocess.Popen(fxswarm_command("run", str(config), "--out", str(tmp_path / "run"), "--no-logger",
                                                "--topology", "routed"),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for_line(launcher, "processes up")
        (router,) = [pid for pid, cmd in children_of(launcher.pid).items() if is_router(cmd)]
        os.kill(router, signal.SIGKILL)
        out, err = launcher.communicate(timeout=300)
    finally:
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGKILL)
            launcher.wait()
    assert launcher.returncode == 0, err
    assert f"router (pid {router}) died: killed by SIGKILL; started it again (restart 1 of at most 10)" in err, err
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["complete"] and summary["missed_ticks"] == 0 and summary["launcher"]["router_restarts"] == 1


def is_router(cmd: str) -> bool:
    """Whether a child's command line is the router's: `fxswarm router ...`, or zenohd (or its
    stand-in) started on the configuration `fxswarm run` writes for it (`-c .../router.zenohd.json5`)."""
    return " router " in cmd or "router.zenohd.json5" in cmd


def test_a_router_started_by_fxswarm_run_dies_with_its_sigkilled_launcher(tmp_path, monkeypatch):
    """zenohd watches no parent: the kernel ends it when its launcher dies (PR_SET_PDEATHSIG),
    SIGKILLed too; the Python roles leave by themselves. Here with the token-less stand-in,
    started as zenohd is (with FXSWARM_ZENOHD set, the real one, `make test-zenohd`)."""
    import subprocess
    import sys
    import time

    from fxswarm.testing import scenario_with

    from support import PAPER_FAST, fxswarm_command
    from test_runtime_shutdown import children_of, gone, wait_for_line

    if not os.environ.get("FXSWARM_ZENOHD"):
        monkeypatch.setenv("FXSWARM_ZENOHD", f"{sys.executable} tests/integration/tokenless_router.py")
    config = scenario_with(PAPER_FAST, tmp_path, duration=600.0)  # still running when its launcher dies
    launcher = subprocess.Popen(fxswarm_command("run", str(config), "--out", str(tmp_path / "run"), "--no-logger",
                                                "--topology", "routed"),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    children: dict[int, str] = {}
    try:
        wait_for_line(launcher, "processes up")
        children = children_of(launcher.pid)
        (router,) = [pid for pid, cmd in children.items() if is_router(cmd)]
        assert "router.zenohd.json5" in children[router]  # started as zenohd is, not `fxswarm router`
        os.kill(launcher.pid, signal.SIGKILL)  # the launcher alone: its children are in sessions of their own
        launcher.wait()
        end = time.monotonic() + 30.0  # the roles notice within their 0.1 s loop; the kernel tells zenohd at once
        while time.monotonic() < end and not all(gone(pid) for pid in children):
            time.sleep(0.05)
        left = {pid: cmd for pid, cmd in children.items() if not gone(pid)}
        assert not left, f"still running 30 s after their launcher was SIGKILLed: {left}"
    finally:
        for pid in children:
            if not gone(pid):
                os.kill(pid, signal.SIGKILL)
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()


def test_health_passes_while_the_router_cannot_be_reached_only_when_asked(tmp_path):
    """A container's check (`fxswarm stack`, `k8s`) must not fail while its router restarts, or
    the orchestrator kills every task; by hand, an unreachable router is still a failure."""
    import subprocess

    from support import fxswarm_command, port_nobody_listens_on

    with port_nobody_listens_on() as port:
        ask = fxswarm_command("health", "agent", "1", "--swarm", "s", "--connect", f"tcp/127.0.0.1:{port}",
                              "--timeout", "0.5", "--quiet")
        plain = subprocess.run(ask, capture_output=True, text=True, timeout=60)
        lenient = subprocess.run([*ask, "--router-down-ok"], capture_output=True, text=True, timeout=60)
    assert plain.returncode == 1 and "cannot reach the router" in plain.stderr
    assert lenient.returncode == 0 and "not judged" in lenient.stderr
