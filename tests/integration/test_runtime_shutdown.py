"""Clean shutdown and deaths, with real processes: no orphans, no deadlock, clear reports.

Outcomes only: how long a stop or a refusal takes depends on the machine's load and is
measured by benchmarks/bench_shutdown.py; the timeouts here only keep a hang from lasting.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fxswarm.runtime.output import load_trajectory
from fxswarm.testing import scenario_with

from support import PAPER_FAST, REPO, fxswarm_command, port_nobody_listens_on


def children_of(pid: int) -> dict[int, str]:
    """{pid: command line} of the live direct children of ``pid``."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            if ppid == pid:
                out[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


def gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    try:  # a zombie counts as gone (it has exited; its parent has not reaped it)
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


def start_launcher(tmp_path: Path, duration: float, *extra: str) -> subprocess.Popen:
    config = scenario_with(PAPER_FAST, tmp_path, duration=duration)
    return subprocess.Popen(fxswarm_command("run", str(config), "--out", str(tmp_path / "run"), "--no-logger", *extra),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def wait_for_line(proc: subprocess.Popen, needle: str, timeout: float = 90.0) -> str:
    """Read the launcher's stderr until a line contains ``needle`` (a message, not a sleep)."""
    end = time.monotonic() + timeout
    seen = []
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if needle in line:
            return line
    raise AssertionError(f"no {needle!r} from the launcher; it said: {''.join(seen)[-2000:]}")


@pytest.mark.zenoh
def test_ctrl_c_stops_every_process_and_says_what_it_stopped(tmp_path):
    launcher = start_launcher(tmp_path, 300.0)
    try:
        wait_for_line(launcher, "processes up")
        kids = children_of(launcher.pid)
        assert len(kids) >= 9, kids  # router, leader, 6 agents, world
        launcher.send_signal(signal.SIGINT)
        _, err = launcher.communicate(timeout=60)  # how fast: benchmarks/bench_shutdown.py ctrl_c_stop_s
        assert launcher.returncode == 130
        assert "stopped" in err and "world" in err
        assert all(gone(pid) for pid in kids), {p: c for p, c in kids.items() if not gone(p)}
    finally:
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGKILL)
            launcher.wait()


@pytest.mark.zenoh
@pytest.mark.parametrize("role", ["world", "leader"])
def test_world_or_leader_death_ends_the_run_non_zero_naming_it(tmp_path, role):
    logs = tmp_path / "run" / "logs"
    logs.mkdir(parents=True)
    (logs / f"{role}.log").write_text("a previous run's last words\n")  # the same --out, run again
    launcher = start_launcher(tmp_path, 300.0)
    try:
        wait_for_line(launcher, "processes up")
        kids = children_of(launcher.pid)
        (victim,) = [pid for pid, cmd in kids.items() if f" {role} " in cmd]
        os.kill(victim, signal.SIGKILL)
        _, err = launcher.communicate(timeout=60)
        assert launcher.returncode == 1
        assert f"{role} (pid {victim}) died: killed by SIGKILL" in err
        assert "a previous run's last words" not in err  # its last output is this run's
        assert all(gone(pid) for pid in kids)
    finally:
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGKILL)
            launcher.wait()


@pytest.mark.zenoh
def test_a_killed_agent_is_reported_and_the_swarm_runs_on_to_the_end(launch_swarm):
    # A tick timeout longer than the test may wait: the run ends only if the world closes the dead
    # robot's ticks at once. (Its wall time: benchmarks/bench_shutdown.py killed_agent_run_wall_s.)
    swarm = launch_swarm(PAPER_FAST, duration=2.0, tick_timeout=600.0)
    pids = swarm.pids()
    swarm.wait_for_sim_time(0.5)
    os.kill(swarm.pid("agent-3"), signal.SIGKILL)  # unplanned: not through the handle
    summary = swarm.wait_done(timeout=120)
    assert [d.child.name for d in swarm.deaths] == ["agent-3"]
    assert summary["complete"] and summary["ticks"] == 200
    # The world closed robot 3's ticks from its death to the end without a timeout each (600 s), and
    # no other robot's. Its death's tick is the world's own record's: robot 3's estimate (from its
    # command) moves every tick it is heard, and is held from then on. (Not the launcher's view of
    # the clock: lock-step runs on while it reacts; once, a kill after t = 0.5 s landed at tick 104.)
    ph3 = load_trajectory(swarm.out)["ph"][:, 2]
    last_heard = int(np.flatnonzero(np.any(ph3[1:] != ph3[:-1], axis=1))[-1]) + 1
    print(f"robot 3 last heard at tick {last_heard}; missed {summary['missed_ticks_per_robot']}")
    assert 50 <= last_heard < 199  # killed after t = 0.5 s, before the end
    assert summary["missed_ticks_per_robot"] == {"1": 0, "2": 0, "3": 199 - last_heard, "4": 0, "5": 0, "6": 0}
    assert "agent-3" not in summary["processes"]  # it never wrote its counters
    assert all(gone(pid) for pid in pids.values())


@pytest.mark.zenoh
def test_a_frozen_agent_costs_missed_ticks_never_a_deadlock_and_a_restart_rejoins(launch_swarm):
    swarm = launch_swarm(PAPER_FAST, duration=60.0, tick_timeout=0.1)
    swarm.wait_for_sim_time(0.3)
    swarm.freeze("agent-2")
    # The world goes on: each tick closes at its deadline. Waited for on the world's own state, not
    # on a count of ticks: the launcher's view of the clock can lag the world by more ticks than a
    # frozen robot costs it (under load, 12 reported ticks once passed with no tick missed).
    swarm.wait_for_silence(2, ticks=6, timeout=60)
    swarm.thaw("agent-2")
    swarm.kill("agent-5")
    swarm.restart("agent-5")  # waits until the new process is alive (the old token gone first)
    swarm.step(20, timeout=60)
    how = swarm.stop()  # SIGTERM: the world writes its (incomplete) summary, everyone their counters
    assert how["world"] == "SIGTERM" and how["agent-5"] == "SIGTERM"
    # A run cut short is no success: `docker compose up --exit-code-from world` must not say 0.
    assert swarm.pid("world") and swarm.swarm.children["world"].popen.returncode == 128 + 15
    summary = swarm.summary()
    counters = swarm.swarm.process_counters()
    assert not summary["complete"] and summary["missed_ticks"] >= 5
    assert summary["missed_ticks_per_robot"]["2"] >= 5
    assert counters["agent-5"]["sent"] > 0 and counters["agent-5"]["received"] > 0  # the restarted agent rejoined
    assert not swarm.deaths


def test_an_exit_at_run_over_is_planned_even_while_the_world_is_still_there(tmp_path):
    # The world waits for its processes to leave once it has ended the run, so an agent may exit
    # (status 0) while the world still runs: what it wrote before exiting says why it left.
    from fxswarm.launch.launcher import Child, Swarm

    swarm = Swarm(str(PAPER_FAST), tmp_path, logger=False)
    world = Child("world", "world", 0, [], tmp_path / "world.log")
    world.popen = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    swarm.alive.add(world.token)
    swarm.children = {"world": world}
    try:
        (tmp_path / "processes").mkdir()
        for ident, reason in ((1, "run over"), (2, "SIGTERM"), (3, None)):
            child = Child(f"agent-{ident}", "agent", ident, [], tmp_path / f"agent-{ident}.log")
            child.popen = subprocess.Popen([sys.executable, "-c", "pass"])
            child.popen.wait()
            if reason is not None:
                (tmp_path / "processes" / f"agent-{ident}.json").write_text(json.dumps({"stop_reason": reason}))
            swarm.children[child.name] = child
        assert sorted(d.child.name for d in swarm.poll(0)) == ["agent-2", "agent-3"]
    finally:
        world.popen.stdin.close()
        world.popen.wait()


# --- bad input, a network that is not there, a folder that cannot be written -----------------


@pytest.mark.zenoh
def test_a_client_waiting_for_its_router_says_so_and_hears_ctrl_c(tmp_path):
    with port_nobody_listens_on() as port:
        proc = subprocess.Popen(fxswarm_command("leader", str(PAPER_FAST), "--swarm", "nobody", "--mode", "client",
                                             "--connect", f"tcp/127.0.0.1:{port}", "--out", str(tmp_path)),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            wait_for_line(proc, f"waiting for the router at tcp/127.0.0.1:{port}", timeout=60)
            proc.send_signal(signal.SIGINT)
            code = proc.wait(timeout=60)  # how fast: benchmarks/bench_shutdown.py client_ctrl_c_s
            assert code == 130
            assert "Traceback" not in proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.mark.zenoh
def test_a_client_gives_up_on_its_router_after_connect_timeout_with_a_clear_error(tmp_path):
    with port_nobody_listens_on() as port:
        done = subprocess.run(fxswarm_command("agent", str(PAPER_FAST), "--id", "2", "--swarm", "nobody",
                                           "--mode", "client", "--connect", f"tcp/127.0.0.1:{port}",
                                           "--connect-timeout", "1.5", "--out", str(tmp_path)),
                              capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert f"fxswarm agent 2: no router answered at tcp/127.0.0.1:{port} within 1.5 s" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.zenoh
@pytest.mark.parametrize("role", ["router", "agent"])
def test_a_port_already_taken_is_a_clear_error_not_a_traceback(tmp_path, role):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        args = (["router", "--listen", endpoint] if role == "router" else
                ["agent", str(PAPER_FAST), "--id", "2", "--mode", "peer", "--no-multicast", "--listen", endpoint])
        done = subprocess.run(fxswarm_command(*args, "--swarm", "nobody"), capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    said = "fxswarm router: cannot listen on" if role == "router" else "fxswarm agent 2: could not open a Zenoh session"
    assert said in done.stderr and "Address already in use" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.zenoh
@pytest.mark.parametrize("topology", ["mesh", "routed"])
def test_a_launcher_whose_router_cannot_listen_says_so_at_once(tmp_path, topology):
    """Its router dies (the port is taken): the launcher reports that death, not a connect timeout
    30 s later (routed: its own session is a client of that router). What it says shows which;
    how long it took is benchmarks/bench_shutdown.py's router_port_taken_s."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        done = subprocess.run(fxswarm_command("run", str(PAPER_FAST), "--out", str(tmp_path / "run"), "--no-logger",
                                           "--port", port, "--topology", topology),
                              capture_output=True, text=True, timeout=120)  # how fast: bench_shutdown.py
    assert done.returncode == 1
    assert "the swarm did not start: router" in done.stderr and "Address already in use" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and "waiting for the router" not in done.stderr, done.stderr


@pytest.mark.parametrize("command", [
    ["sim", str(PAPER_FAST), "--out", "{blocked}"],
    ["run", str(PAPER_FAST), "--out", "{blocked}"],
    ["world", str(PAPER_FAST), "--swarm", "nobody", "--out", "{blocked}"],
    ["agent", str(PAPER_FAST), "--id", "2", "--swarm", "nobody", "--out", "{blocked}"],
    ["logger", str(PAPER_FAST), "--swarm", "nobody", "--out", "{blocked}"],
    ["sweep", str(PAPER_FAST), "--out", "{blocked}"],
], ids=lambda c: c[0])
def test_a_run_folder_that_cannot_be_written_is_refused_before_any_work(tmp_path, command):
    (tmp_path / "a-file").write_text("")
    blocked = str(tmp_path / "a-file" / "run")  # a folder under a file: not a directory
    done = subprocess.run(fxswarm_command(*(a.format(blocked=blocked) for a in command)),
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    assert f"cannot write the run folder {blocked}: Not a directory" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    # Refused up front, not after the run: nothing ran, so nothing was printed but the refusal.
    # (How fast: benchmarks/bench_shutdown.py refuse_unwritable_out_s.)
    assert done.stdout == "" and done.stderr.strip().count("\n") == 0, done.stderr


@pytest.mark.parametrize("role", ["run", "world", "agent"])
def test_a_wrong_fault_spec_is_refused_by_the_launcher_and_by_each_role(tmp_path, role):
    extra = ["--id", "2"] if role == "agent" else []
    done = subprocess.run(fxswarm_command(role, str(PAPER_FAST), *extra, "--swarm", "nobody", "--out", str(tmp_path),
                                       "--fault", "agent:1->agent:2 drop=2"),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    # The error names the flag and the spec it came from (resolved once, at this command's edge).
    said = "--fault 'agent:1->agent:2 drop=2': faults.links[0].drop: expected a probability in [0, 1], got 2.0"
    assert said in done.stderr and "Traceback" not in done.stderr, done.stderr


@pytest.mark.parametrize("command, said", [
    (["run", "--speed", "0"], "argument --speed: expected a number > 0, got '0'"),
    (["run", "--tick-timeout", "0"], "argument --tick-timeout: expected a number > 0, got '0'"),
    (["run", "--max-lag", "-1"], "argument --max-lag: expected an integer >= 0, got '-1'"),
    (["run", "--port", "70000"], "argument --port: expected a TCP port in 1..65535, got '70000'"),
    (["world", "--tick-timeout", "nan"], "argument --tick-timeout: expected a finite number, got 'nan'"),
    (["agent", "--id", "2", "--speed", "-4"], "argument --speed: expected a number > 0, got '-4'"),
    (["leader", "--world-timeout", "-1"], "argument --world-timeout: expected a number >= 0, got '-1'"),
    (["sweep", "--workers", "0"], "argument --workers: expected an integer > 0, got '0'"),
    (["logger", "--rate", "0"], "argument --rate: expected a number > 0, got '0'"),
    # A negative --timeout became a connect wait with no end.
    (["attach", "--swarm", "s", "--timeout", "-5"], "argument --timeout: expected a number > 0, got '-5'"),
    # Lock-step runs as fast as it can: a pace given without real time was silently ignored.
    (["run", "--speed", "2"], "fxswarm run: --speed set real time's pace: add --clock realtime"),
    (["run", "--clock", "lockstep", "--speed", "1", "--max-lag", "3"],
     "fxswarm run: --speed and --max-lag set real time's pace: add --clock realtime"),
])
def test_a_number_out_of_range_is_refused_in_one_line_before_anything_starts(tmp_path, command, said):
    """Before, ``run --speed 0`` started every process and each died with a traceback, and
    ``--tick-timeout 0`` ran the whole lock-step run on missed ticks and exited 0."""
    role, *options = command
    done = subprocess.run(fxswarm_command(role, str(PAPER_FAST), *options, "--out", str(tmp_path / "run")),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert said in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert not (tmp_path / "run").exists()  # refused before any work


@pytest.mark.zenoh
def test_a_process_that_cannot_write_its_counters_still_closes_its_session_and_exits(tmp_path):
    """An open Zenoh session keeps a process from exiting: whatever fails on the way out, it is closed."""
    (tmp_path / "processes").write_text("")  # where the counters go: a file, not a folder
    proc = subprocess.Popen(fxswarm_command("world", str(PAPER_FAST), "--swarm", f"nobody-{os.getpid()}",
                                         "--out", str(tmp_path), "--wait-timeout", "1", "--no-multicast"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        code = proc.wait(timeout=60)
        said = proc.stderr.read()
        assert code == 3, said  # gave up waiting for the swarm
        assert "could not write its counters" in said and "Traceback" not in said, said
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.zenoh
def test_quiet_hides_the_chatter_but_not_an_interruption(tmp_path):
    launcher = start_launcher(tmp_path, 300.0, "--quiet")
    try:
        end = time.monotonic() + 60
        while len(kids := children_of(launcher.pid)) < 9:  # started, whether up or still coming up
            assert launcher.poll() is None and time.monotonic() < end, kids
            time.sleep(0.05)
        launcher.send_signal(signal.SIGINT)
        _, err = launcher.communicate(timeout=60)
        assert launcher.returncode == 130
        # The user learns the run was cut short and what was stopped, quiet or not.
        assert "fxswarm run: interrupted" in err and "stopped" in err, err
        assert "processes up" not in err
        assert all(gone(pid) for pid in kids)
    finally:
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGKILL)
            launcher.wait()


@pytest.mark.zenoh
def test_the_liveliness_benchmark_sees_a_killed_and_a_frozen_subject_go(tmp_path):
    """benchmarks/bench_liveliness.py, which holds the "seen gone at once, not by the lease"
    timing the docker rejoin test prints only, runs against a real router: every case's token is
    seen to go (a subject the watcher never sees go fails the script), a frozen one only by its lease."""
    out = tmp_path / "liveliness.json"
    done = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bench_liveliness.py"), "--rounds", "1",
                           "--lease-ms", "3000", "--out", out], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    runs = json.loads(out.read_text())["runs_s"]
    assert sorted(runs) == ["frozen_s", "killed_s", "left_s"] and all(len(v) == 1 and v[0] > 0 for v in runs.values())
    # Nothing closes a frozen session: the router drops it a lease after the last keep-alive it
    # heard, and Zenoh sends one every quarter lease, so 0.75-1 lease after the freeze (0.99 s of
    # a 1 s lease seen); half a lease tells that from a subject killed instead of frozen.
    assert runs["frozen_s"][0] >= 1.5
