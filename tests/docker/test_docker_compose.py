"""The compose swarm on the real Docker engine: run, kill, disconnect, tear down.

Every test here needs a Docker engine and a compose tool (``docker compose``
or ``docker-compose``). Where none answers they skip and say why; where
``FXSWARM_REQUIRE_DOCKER=1`` (``.ci/run`` sets it when ``docker info``
answers) a skip becomes a failure, so CI cannot go green by skipping them.

One set of images for the whole session: ``docker/build-images.sh`` (no
registry: the base images by debootstrap + ``docker import`` + offline wheels,
skipped when already there; then one slim image per role family, tag ``test``).
Each compose project runs the top-level ``docker-compose.yml`` copied into a
temporary folder (its ``./runs`` lands there), under a unique project name
and swarm name, and is brought down in a finaliser even when a test fails.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import shutil
import subprocess
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.metrics import formation_errors
from fxswarm.core.scenario import load
from fxswarm.faults.plan import DegradedLimits

from docker_support import TAG, compose_command, run as _run
from support import PAPER_FAST, REPO, measured

# The first test also waits for the images (from a clean machine: ~4 min base image + ~1.5 min
# project image) and a compose run: more than the suite's default 600 s may pass under load.
pytestmark = [pytest.mark.docker, pytest.mark.timeout(1500)]

SCENARIO = PAPER_FAST
ROLES = ["router", "logger", "leader", *(f"agent-{i}" for i in range(1, 7)), "world"]


# --- one compose project ---------------------------------------------------------------------


class ComposeProject:
    """The top-level docker-compose.yml, run from a temporary folder under a unique project name."""

    def __init__(self, folder: Path, image: str, scenario_text: str | None = None, **variables: str) -> None:
        self.folder = folder
        scenario = SCENARIO
        if scenario_text is not None:  # a variant of the scenario, mounted in place of it
            scenario = folder / "scenario.toml"
            scenario.write_text(scenario_text)
        self.tool = compose_command()
        self.name = f"fxtest{uuid.uuid4().hex[:10]}"
        self.swarm = f"docker-{self.name}"
        self.run_name = "run"
        shutil.copy(REPO / "docker-compose.yml", folder / "docker-compose.yml")
        (folder / "runs").mkdir()
        (folder / "runs").chmod(0o777)  # the containers run as uid 10001, not as this user
        self.env = {**os.environ, "FXSWARM_TAG": TAG, "FXSWARM_SWARM": self.swarm,
                    "FXSWARM_SCENARIO": str(scenario), "FXSWARM_RUN": self.run_name,
                    "FXSWARM_ROUTER_PUBLISH": "127.0.0.1:",  # an ephemeral host port
                    **variables}
        self.down_done = False

    @property
    def out(self) -> Path:
        return self.folder / "runs" / self.run_name

    def compose(self, *args: str, timeout: float = 120) -> str:
        return _run([*self.tool, "-p", self.name, *args], timeout, f"compose {args[0]}", self.env, self.folder)

    def up(self) -> None:
        self.compose("up", "-d", "--no-build", timeout=600)  # waits for the logger: minutes at load 50

    def container(self, service: str) -> str:
        cid = self.compose("ps", "-a", "-q", service).strip()
        assert cid, f"no container for service {service} in project {self.name}"
        return cid.splitlines()[0]

    def router_endpoint(self) -> str:
        port = _run(["docker", "port", self.container("router"), "7447"], 30, "docker port").split(":")[-1]
        return f"tcp/127.0.0.1:{int(port)}"

    def network(self) -> str:
        return f"{self.name}_default"

    def wait_exit(self, service: str, timeout: float) -> int:
        """Wait for ``service``'s container to stop; its exit code."""
        return int(_run(["docker", "wait", self.container(service)], timeout, f"docker wait {service}").strip())

    def state(self, service: str) -> dict:
        return json.loads(_run(["docker", "inspect", "-f", "{{json .State}}", self.container(service)], 30,
                               "docker inspect"))

    def logs(self) -> str:
        try:
            return self.compose("logs", "--no-color", "--tail", "15", timeout=60)
        except BaseException:  # noqa: BLE001 - logs only decorate a failure
            return "(no logs)"

    def down(self) -> None:
        self.down_done = True
        self.compose("down", "-v", "--remove-orphans", "--timeout", "5", timeout=180)

    def leftovers(self) -> list[str]:
        """Containers or networks of this project still on the engine."""
        label = f"label=com.docker.compose.project={self.name}"
        ids = _run(["docker", "ps", "-a", "-q", "--filter", label], 30, "docker ps").split()
        nets = _run(["docker", "network", "ls", "-q", "--filter", label], 30, "docker network ls").split()
        return [f"container {c}" for c in ids] + [f"network {n}" for n in nets]

    def summary(self) -> dict:
        path = self.out / "summary.json"
        assert path.exists(), f"no {path}; the compose logs:\n{self.logs()}"
        return json.loads(path.read_text())

    def counters(self, process: str) -> dict:
        return json.loads((self.out / "processes" / f"{process}.json").read_text())


@pytest.fixture(scope="module")
def project_factory(role_images):
    """Make compose projects; bring every one down at the end, whatever happened.

    Each lives in a folder of its own under /tmp, not pytest's tmp_path: pytest keeps only
    the last three sessions' folders, and a parallel session could delete a running one's runs.
    """
    made: list[ComposeProject] = []

    def make(scenario_text: str | None = None, **variables: str) -> ComposeProject:
        p = ComposeProject(Path(tempfile.mkdtemp(prefix="fxswarm-compose-")), role_images, scenario_text,
                           **variables)
        made.append(p)
        return p

    yield make
    for p in made:
        if not p.down_done or p.leftovers():
            try:
                p.down()
            except BaseException:  # noqa: BLE001 - go on with the others
                pass
        if os.geteuid() != 0 and p.out.exists():  # files the containers (uid 10001) wrote
            subprocess.run(["docker", "run", "--rm", "--user", "0", "--entrypoint", "chown", "-v", f"{p.folder}/runs:/r",
                            role_images, "-R", f"{os.getuid()}:{os.getgid()}", "/r"], capture_output=True)
        if os.environ.get("FXSWARM_KEEP_COMPOSE_RUNS") != "1":  # =1 keeps them to look at
            shutil.rmtree(p.folder, ignore_errors=True)


def wait_until(what: str, done, timeout: float, step: float = 0.2):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = done()
        if value:
            return value
        time.sleep(step)
    pytest.fail(f"timed out after {timeout:g} s waiting for {what}")


# --- the paper scenario, lock-step: the outcome ------------------------------------------------


@dataclass
class FinishedRun:
    project: ComposeProject
    exit_codes: dict[str, int]
    took_s: float


@pytest.fixture(scope="module")
def paper_run(project_factory) -> FinishedRun:
    """``compose up`` of the paper scenario (lock-step) run to its end: every role exits by itself."""
    p = project_factory(FXSWARM_CLOCK="lockstep")
    start = time.monotonic()
    p.up()
    codes = {"world": p.wait_exit("world", 420)}
    for role in ROLES:
        if role not in ("router", "world"):  # they leave once the world is gone (liveliness)
            codes[role] = p.wait_exit(role, 60)
    return FinishedRun(p, codes, time.monotonic() - start)


@pytest.mark.slow
def test_compose_up_paper_runs_to_completion_with_the_paper_outcome(paper_run):
    p = paper_run.project
    assert paper_run.exit_codes == {r: 0 for r in paper_run.exit_codes}, p.logs()
    s = p.summary()
    print(f"compose run ({' '.join(p.tool)}): {paper_run.took_s:.0f} s from up to every role gone; world {s['ticks']} ticks in "
          f"{s['wall_s']:.1f} s; {json.dumps({k: s[k] for k in ('min_object_distance_m', 'formation_error_final_m', 'estimate_error_final_m', 'estimate_settle_s')})}")
    assert s["complete"] and s["clock"] == "lockstep" and s["missed_ticks"] == 0
    assert s["min_object_distance_m"] >= 1.8
    assert s["formation_error_final_m"] <= 0.15
    assert s["estimate_error_final_m"] <= 0.15
    assert s["estimate_settle_s"] is not None and s["estimate_settle_s"] <= 5
    assert len(s["avoidance_episodes"]) >= 1
    # The logger recorded the run into the mounted ./runs, and every process left its counters.
    assert (p.out / "recording.rrd").stat().st_size > 100_000
    assert {f.stem for f in (p.out / "processes").glob("*.json")} == \
        {"world-0", "leader-0", "logger-0", *(f"agent-{i}" for i in range(1, 7))}


@pytest.mark.slow
def test_compose_lockstep_run_equals_the_in_process_simulator(paper_run):
    """Containers change nothing: the same trajectory, bit for bit, as ``fxswarm sim``."""
    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation

    sim = Simulation(load(SCENARIO))
    sim.run()
    expected = sim.trajectory()
    with np.load(paper_run.project.out / "trajectory.npz") as got:
        assert sorted(got.files) == sorted(expected)
        for key in expected:
            assert np.array_equal(got[key], expected[key]), key


@pytest.mark.slow
def test_compose_down_leaves_nothing_running(paper_run):
    p = paper_run.project
    assert p.state("router")["Running"], "the router serves until compose down"
    p.down()
    assert p.leftovers() == []


# --- the paper scenario in real time, broken from outside -------------------------------------


@dataclass
class FaultObservations:
    """What a test-side Zenoh client (through the published router port) saw during the run."""

    killed_at_t: float = 0.0  # simulation time of the docker kill, s
    gone_after_s: float = 0.0  # wall time from the kill to agent/3's liveliness token gone
    back_after_s: float = 0.0  # wall time from docker start to agent/3 alive again
    rejoined_at_t: float = 0.0  # simulation time of agent 3's first command after its restart
    cut_at_t: float = 0.0  # simulation time of the network disconnect of agent 5
    cut_s: float = 0.0  # wall seconds agent 5 was off the network
    silent_wall_s: float = 0.0  # longest wall gap between agent 5's commands reaching the observer
    gap_before_cut_s: float = 0.0  # the same, over the run before the cut (its ordinary gaps)
    stalest_s: float = 0.0  # oldest (simulation s behind the swarm) a command of agent 5 arrived
    resumed_at_t: float = 0.0  # simulation time of agent 5's first fresh command after the cut
    stopped_at_t: float = 0.0  # the world's time when the test stopped it (SETTLE_S after that)
    alive_changes: list[tuple[str, bool]] = field(default_factory=list)
    exit_codes: dict[str, int] = field(default_factory=dict)


class Observer:
    """A Zenoh client of the compose router: liveliness of the agents, their commands' times."""

    def __init__(self, endpoint: str, swarm: str) -> None:
        from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions

        self.bus = ZenohBus(swarm, ZenohOptions("client", (endpoint,), (), False))
        self.alive: set[str] = set()
        self.changes: list[tuple[str, bool]] = []
        # (arrival wall s, msg.t, age): age = the newest simulation time heard from anyone
        # minus msg.t, i.e. how stale the command is when it reaches the observer, s.
        self.cmds: dict[int, list[tuple[float, float, float]]] = {3: [], 5: []}
        self.newest_t = 0.0
        self.world_t = -1.0  # the world's own clock, from world/state (agents' commands lag it)
        self.bus.watch_alive("agent/*", self._on_alive)
        for robot in self.cmds:
            self.bus.subscribe(f"agent/{robot}/cmd", self._on_cmd)
        self.bus.subscribe("world/state", self._on_state)

    def _on_alive(self, name: str, up: bool) -> None:
        self.changes.append((name, up))
        (self.alive.add if up else self.alive.discard)(name)

    def _on_cmd(self, topic: str, msg) -> None:
        self.newest_t = max(self.newest_t, msg.t)
        self.cmds[msg.robot].append((time.monotonic(), msg.t, self.newest_t - msg.t))

    def _on_state(self, topic: str, msg) -> None:
        self.world_t = max(self.world_t, msg.t)

    def latest_t(self, robot: int) -> float:
        return self.cmds[robot][-1][1] if self.cmds[robot] else -1.0

    def wait(self, what: str, done, timeout: float) -> None:
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() > end:
                pytest.fail(f"timed out after {timeout:g} s waiting for {what}")
            self.bus.poll(0.05)

    def close(self) -> None:
        self.bus.close()


#: How long agent 5 stays off the network, wall s (the fault itself, not a wait): well inside
#: the Zenoh lease, so nobody gives it up; a cut past the lease is the last test of this file.
CUT_S = 2.0
FRESH_S = 0.2  # a command at most this far (simulation s) behind the swarm's newest is fresh
REJOIN_SETTLE_S = 10.0  # simulation s a restarted robot gets to fly back into formation
SILENT_HOLD_S = DegradedLimits.silent_hold  # the world holds a robot silent longer than this at zero velocity
# The real-time runs end when the test has seen what it judges (the faults, the recovery from each,
# the settling after it): the test stops the world then (SIGINT, as a user ends a run), so a quiet
# machine flies ~30 s, not the length the worst load needs. The scenario's duration is only the
# cap. 11 runs at load 18-34 (2 cores, another suite running): broken_run cut robot 5 at t = 27-51 s
# (robot 3 dead 12-36 s), robot 5 was fresh again 1.7-24 s after its cut and 0.03 m off its slot
# 8 s after that; 2 of 3 runs of 55 s ended before it was fresh. Worst 51 + 24 + 8 = 83 s: 95 s.
BROKEN_RUN_S = 95.0
SETTLE_S = 10.0  # simulation s the swarm flies on after the last recovery before the test stops it
# The cut past the lease: robot 5 flying again at t = 15-44 s, 7 s later still 3.3 m off its slot,
# 11 s later 0.02 m; 2 of 4 runs of 45 s ended before it was back. Worst 44 + 11 = 55 s: 70 s.
LEASE_RUN_S = 70.0
LEASE_SETTLE_S = 15.0  # simulation s flown after robot 5 is back (11 s brought it to 0.02 m)
STOPPED = 128 + 2  # the world's exit status when stopped by SIGINT (world/process.py exit_status)
# Formation errors are judged at the stop, so the stop comes after the path's obstacles: the swarm
# of the simulator (undisturbed) ends its last avoidance at t = 29.9 s and is back under 0.06 m
# 2 s later; a stop inside an avoidance finds a robot metres off (0.64 m at t = 29.2 s, once).
AVOIDANCE_SETTLE_S = 5.0


@functools.cache
def obstacles_behind_t() -> float:
    """Simulation time from which the paper-fast path (at its longest here) has no obstacle left
    to avoid: the simulator's last avoidance episode's end plus AVOIDANCE_SETTLE_S."""
    from fxswarm.launch.sim import Simulation

    sim = Simulation(dataclasses.replace(load(SCENARIO), duration=BROKEN_RUN_S))
    episodes = sim.run()["avoidance_episodes"]
    return max((e["end_s"] for e in episodes), default=0.0) + AVOIDANCE_SETTLE_S


def stop_world_at(p: ComposeProject, watcher: Observer, t: float, cap: float) -> float:
    """Let the world fly to simulation time ``t`` (not before the path's last obstacle is behind
    the swarm), then stop it as a user ends a run (SIGINT): it writes its summary and trajectory,
    the agents leave. The world's time when it was told to stop. If ``t`` does not come a second
    before the scenario's ``cap`` (at load 20-31, another compose swarm beside, robot 5 was fresh
    again only at t = 92.6 s of 95), or the signal lands after the world's last tick, the world
    ends its run complete at the cap, as every run did before, and that is judged alike."""
    t = max(t, obstacles_behind_t())
    if t > cap - 1.0:  # the load slowed the faults past the cap: the run ends there, complete, as it used to
        print(f"the world flies to its cap ({cap:g} s): t = {t:.1f} s was needed")
        return cap
    world = p.container("world")  # before the wait: compose ps takes seconds under load
    watcher.wait(f"the world at t = {t:.1f} s", lambda: watcher.world_t >= t, 240)
    subprocess.run(["docker", "kill", "--signal", "INT", world], capture_output=True, timeout=30)
    return watcher.world_t


def assert_stopped_by_the_test(p: ComposeProject, code: int, stopped_at_t: float) -> dict:
    """The world flew on through the faults until the test stopped it: exit 130 (SIGINT), not 1
    (a run the world cut short itself) nor a crash, ``stop_reason`` SIGINT in its counters, and a
    trajectory that reaches the stop; or, the signal landing after its last tick, it ended its run
    complete (exit 0). Its summary."""
    s = p.summary()
    assert s["clock"] == "realtime"
    if code == 0 and s["complete"]:
        return s
    assert code == STOPPED, f"world exit {code}, not {STOPPED} (stopped by the test's SIGINT)\n{p.logs()}"
    assert p.counters("world-0")["stop_reason"] == "SIGINT"
    assert s["ticks"] * load(SCENARIO).dt >= stopped_at_t - 0.5, (s["ticks"], stopped_at_t)
    return s


def flying_realtime_swarm(project_factory, duration: float) -> tuple[ComposeProject, Observer]:
    """The paper scenario as a compose project in real time (speed 1), ``duration`` s long: up,
    watched, every agent alive and robot 5 flying past t = 5 s."""
    text = SCENARIO.read_text()
    assert "duration = 40.0" in text
    p = project_factory(text.replace("duration = 40.0", f"duration = {duration}"), FXSWARM_CLOCK="realtime",
                        FXSWARM_SPEED="1")
    p.up()
    watcher = Observer(p.router_endpoint(), p.swarm)
    try:
        watcher.wait("all six agents alive", lambda: len(watcher.alive) == 6, 120)
        watcher.wait("simulation time 5 s", lambda: watcher.latest_t(5) >= 5.0, 120)
    except BaseException:
        watcher.close()
        raise
    return p, watcher


@pytest.fixture(scope="module")
def broken_run(project_factory) -> tuple[ComposeProject, FaultObservations]:
    """The paper scenario in real time (speed 1), at most BROKEN_RUN_S instead of 40 s (room for
    both faults and the recovery from each on a loaded machine); agent 3 killed and started again,
    agent 5 cut off the network for a few seconds; stopped SETTLE_S after robot 5 is fresh again."""
    p, watcher = flying_realtime_swarm(project_factory, BROKEN_RUN_S)
    obs = FaultObservations()
    try:
        # docker kill: the process dies with its container; liveliness says so at once.
        agent3 = p.container("agent-3")
        _run(["docker", "kill", agent3], 30, "docker kill agent-3")
        t0 = time.monotonic()
        obs.killed_at_t = watcher.latest_t(5)
        watcher.wait("agent/3 seen gone", lambda: "agent/3" not in watcher.alive, 30)
        obs.gone_after_s = time.monotonic() - t0
        heard = len(watcher.cmds[3])  # everything robot 3 said before it died
        # The silence must outlast the world's silent hold on the world's own clock: agents'
        # commands lag it (the real-time world goes on when a robot is late), so a fast docker
        # start could otherwise bring robot 3 back before the world had flown the hold without it.
        died_world_t = watcher.world_t
        watcher.wait("the world flying on without robot 3 past its silent hold",
                     lambda: watcher.world_t >= died_world_t + SILENT_HOLD_S + 0.2, 60)
        t0 = time.monotonic()
        _run(["docker", "start", agent3], 60, "docker start agent-3")
        watcher.wait("agent/3 alive again", lambda: "agent/3" in watcher.alive, 90)
        obs.back_after_s = time.monotonic() - t0
        watcher.wait("a command from robot 3 after its restart", lambda: len(watcher.cmds[3]) > heard, 60)
        obs.rejoined_at_t = watcher.cmds[3][heard][1]

        # Give robot 3 time to close on its slot before the next fault (judged at the cut).
        watcher.wait("10 s of flight after robot 3 rejoined",
                     lambda: watcher.latest_t(5) >= obs.rejoined_at_t + REJOIN_SETTLE_S, 60)

        # docker network disconnect: the container lives on, deaf and mute, for CUT_S seconds.
        agent5 = p.container("agent-5")
        heard = len(watcher.cmds[5])
        obs.gap_before_cut_s = float(np.diff([w for w, _, _ in watcher.cmds[5]]).max())
        obs.cut_at_t = watcher.latest_t(5)
        t0 = time.monotonic()
        _run(["docker", "network", "disconnect", p.network(), agent5], 30, "network disconnect")
        end = time.monotonic() + CUT_S
        while time.monotonic() < end:
            watcher.bus.poll(0.05)
        _run(["docker", "network", "connect", p.network(), agent5], 30, "network connect")
        obs.cut_s = time.monotonic() - t0
        reconnected = len(watcher.cmds[5])

        def fresh_again() -> bool:
            return any(age < FRESH_S for _, _, age in watcher.cmds[5][reconnected:])

        try:
            watcher.wait("a fresh command from robot 5 after the reconnect", fresh_again, 60)
        except pytest.fail.Exception:
            ages = [age for _, _, age in watcher.cmds[5][reconnected:]]
            measured("docker-broken-run-unresumed", load1=os.getloadavg()[0], killed_at_t=obs.killed_at_t,
                     rejoined_at_t=obs.rejoined_at_t, cut_at_t=obs.cut_at_t, world_t=watcher.world_t,
                     cmds5_since=len(ages), youngest_age_s=min(ages, default=-1.0))
            raise
        after = np.array(watcher.cmds[5][max(0, heard - 1):])
        obs.silent_wall_s = float(np.diff(after[:, 0]).max())
        obs.stalest_s = float(after[:, 2].max())
        obs.resumed_at_t = next(t for _, t, age in watcher.cmds[5][reconnected:] if age < FRESH_S)
        # The faults' liveliness, taken before the stop: every agent leaves at the end of the run,
        # and a loaded watcher can see that end during the wait for the stop (the run flew to its
        # cap while the watcher was a cut behind, at load 13).
        obs.alive_changes = list(watcher.changes)
        obs.stopped_at_t = stop_world_at(p, watcher, obs.resumed_at_t + SETTLE_S, BROKEN_RUN_S)
    finally:
        watcher.close()
    obs.exit_codes["world"] = p.wait_exit("world", 240)
    return p, obs


@pytest.mark.slow
def test_docker_kill_and_start_of_an_agent_rejoins_the_swarm(broken_run):
    p, obs = broken_run
    print(f"kill at t = {obs.killed_at_t:.2f} s: seen gone after {obs.gone_after_s:.2f} s; docker start -> "
          f"alive after {obs.back_after_s:.1f} s; first command again at t = {obs.rejoined_at_t:.2f} s")
    s = assert_stopped_by_the_test(p, obs.exit_codes["world"], obs.stopped_at_t)
    dead_s = obs.rejoined_at_t - obs.killed_at_t
    with np.load(p.out / "trajectory.npz") as traj:
        t, err = traj["t"], formation_errors({k: traj[k] for k in ("p", "p0", "offsets")})
    j, k = (int(np.searchsorted(t, x)) for x in (obs.rejoined_at_t, obs.cut_at_t))
    print(f"robot 3 formation error {err[j, 2]:.3f} m when it rejoined at t = {t[j]:.2f} s, {err[k, 2]:.3f} m "
          f"{t[k] - t[j]:.1f} s later (worst robot then {err[k].max():.3f} m: avoidance), "
          f"{err[-1, 2]:.3f} m at the end")
    measured("docker-rejoin", load1=os.getloadavg()[0], gone_after_s=obs.gone_after_s,
             back_after_s=obs.back_after_s, dead_s=dead_s, rejoined_at_t=obs.rejoined_at_t,
             cut_at_t=obs.cut_at_t, stopped_at_t=obs.stopped_at_t, err3_at_cut_m=float(err[k, 2]),
             err3_final_m=float(err[-1, 2]), min_object_distance_m=s["min_object_distance_m"])
    # Real-time figures: 9 runs at load 19-34 (2 cores, another suite running; MEASURED docker-rejoin).
    # Seen gone 0.24-13 s after the kill: a token left to run out its lease goes some 10 s after,
    # inside that spread (the watcher itself lags seconds at this load), so "at once, not by the
    # lease" is printed only (measured on a quiet machine by benchmarks/bench_liveliness.py); that it
    # goes at all, broken_run waits for (30 s).
    assert ("agent/3", False) in obs.alive_changes and obs.alive_changes[-1:] != [("agent/3", False)]
    # While it was dead the world held robot 3 still and its neighbours saw its estimate go stale
    # (both in the record). How long it was dead depends on how fast docker starts a container,
    # so the test asks that the silence is there, not how many ticks it lasted.
    held = s["faults"]["degraded_ticks"]
    assert dead_s > SILENT_HOLD_S, f"robot 3 was silent only {dead_s:.2f} s: too short to test the hold"
    assert held.get("world_held_at_zero", {}).get("3", 0) > 0, held
    sc = load(SCENARIO)
    assert sum(held.get("stale_neighbour", {}).get(str(j), 0) for j in sc.neighbours(3)) > 0, held
    # ... and once back it flew in formation again (judged before the network fault that follows):
    # it rejoined 5.5-22 m off its slot, 10 s later it was 0.03-0.59 m off (bound 2 m: 3.4 x the
    # worst; a robot that does not fly back stays metres off), at the end 0.006-0.09 m (0.5 m: 5.7 x;
    # those runs flew to t = 95 s; stopped SETTLE_S after robot 5's recovery, see MEASURED docker-rejoin).
    # Stopped so, 20 runs at load 8-22: 0.005-0.49 m 10 s after it rejoined, 0.011-0.056 m at the end.
    assert err[k, 2] <= 2.0, "closing on its slot before the next fault"
    assert err[-1, 2] <= 0.5
    # Closest to an object: 1.60-1.91 m (mean 1.81, sd 0.10; the repulsive zone is 2 m): 1.2 m is
    # mean - 6 sd, the worst less 0.4 m; an avoidance that lets a robot 0.8 m into the zone fails.
    # (1.88-1.98 m in the 20 runs stopped once judged, load 8-22.)
    assert s["min_object_distance_m"] >= 1.2


@pytest.mark.slow
def test_docker_network_disconnect_is_seen_as_staleness_and_recovered_from(broken_run):
    p, obs = broken_run
    s = assert_stopped_by_the_test(p, obs.exit_codes["world"], obs.stopped_at_t)
    latency = s["sense_to_command"]
    print(f"agent 5 off the network {obs.cut_s:.1f} s from t = {obs.cut_at_t:.2f} s: no command of it "
          f"arrived for {obs.silent_wall_s:.2f} s, the stalest was {obs.stalest_s:.2f} s behind the swarm, "
          f"fresh again at t = {obs.resumed_at_t:.2f} s; the world's worst sensing-to-command "
          f"latency {latency['max_ms']:.0f} ms; degraded ticks {s['faults']['degraded_ticks']}; the world's "
          f"longest silence per robot {s['longest_silence_s']} s")
    with np.load(p.out / "trajectory.npz") as traj:
        err = formation_errors({k: traj[k] for k in ("p", "p0", "offsets")})
    print(f"robot 5 final formation error {err[-1, 4]:.3f} m (worst robot {err[-1].max():.3f} m)")
    measured("docker-disconnect", load1=os.getloadavg()[0], cut_s=obs.cut_s, silent_wall_s=obs.silent_wall_s,
             world_silence5_s=s["longest_silence_s"]["5"], gap_before_cut_s=obs.gap_before_cut_s,
             world_silence_others_s=max(v for r, v in s["longest_silence_s"].items() if r not in ("3", "5")),
             resumed_after_t_s=obs.resumed_at_t - obs.cut_at_t, stopped_at_t=obs.stopped_at_t,
             stalest_s=obs.stalest_s, err5_final_m=float(err[-1, 4]))
    # Seen: nothing of robot 5 crosses the cut, as a watcher on the router sees it and as the
    # world does: its longest wait for a new command of robot 5 (summary longest_silence_s). What
    # the world did meanwhile varies with where Zenoh's queues fill (held its clock for the deaf
    # robot, or answered its sensing a cut late, or neither stood out), so that is printed only.
    # Both are floors load only raises (9 runs at load 19-34: 3.3-25 s at the watcher, 3.1-4.0 s at
    # the world, for a 2.2-4.1 s cut). Loaded, they do not tell the cut from a stall: robot 5's
    # longest gap before the cut was 8.9-21 s at the watcher and the world's longest silence of an
    # uncut robot 3.2-5.0 s; only on a quiet machine do they catch a cut that cut nothing.
    assert obs.silent_wall_s >= 0.5 * CUT_S, "no command of robot 5 crosses a cut network"
    assert s["longest_silence_s"]["5"] >= 0.5 * CUT_S, s["longest_silence_s"]
    # Recovered: never taken for dead (the cut is shorter than the lease), fresh again (broken_run
    # waits for it), the world flying on until stopped (assert_stopped_by_the_test), and robot 5
    # ends in formation. How long it took is printed only: 1.7-24 s of simulation after the cut in
    # those runs (in 2 more, a 55 s run ended first), too spread to bound.
    assert ("agent/5", False) not in obs.alive_changes, "a cut shorter than the lease is no death"
    # 0.03 m off its slot 8 s after it was fresh, in those runs; 0.006-0.07 m at their end (t = 95 s):
    # 0.5 m is 7 x the worst; left behind, metres. Stopped SETTLE_S after it was fresh: 0.008-0.056 m
    # in 20 runs at load 8-22 (the stop landed at t = 55.9-95 s: a loaded watcher is behind).
    assert err[-1, 4] <= 0.5


@pytest.mark.slow
def test_docker_network_cut_past_the_lease_the_agent_waits_for_the_world_and_rejoins(project_factory):
    """Agent 5 off the network until the router has given it up (the Zenoh lease, 10 s), and its
    own session the world: it must wait for the world (it did not end the run), take it back
    when the network does, and fly on; the world flies on until the test stops it, LEASE_SETTLE_S
    after robot 5 is back."""
    p, watcher = flying_realtime_swarm(project_factory, LEASE_RUN_S)
    try:
        agent5 = p.container("agent-5")
        t0 = time.monotonic()
        _run(["docker", "network", "disconnect", p.network(), agent5], 30, "network disconnect")
        watcher.wait("agent/5 given up by the router (its lease ran out)", lambda: "agent/5" not in watcher.alive, 60)
        end = time.monotonic() + 2.0  # the fault goes on a little: agent 5's own lease runs out too
        while time.monotonic() < end:
            watcher.bus.poll(0.05)
        _run(["docker", "network", "connect", p.network(), agent5], 30, "network connect")
        cut_s = time.monotonic() - t0
        heard = len(watcher.cmds[5])
        watcher.wait("agent/5 alive again", lambda: "agent/5" in watcher.alive, 90)
        watcher.wait("a command from robot 5 after the reconnect", lambda: len(watcher.cmds[5]) > heard, 90)
        back_at_t = watcher.cmds[5][heard][1]
        stopped_at_t = stop_world_at(p, watcher, back_at_t + LEASE_SETTLE_S, LEASE_RUN_S)
    finally:
        watcher.close()
    code = p.wait_exit("world", 240)
    said = [line for line in p.logs().splitlines() if "agent-5" in line and "fxswarm agent 5" in line]
    print(f"agent 5 off the network {cut_s:.1f} s, flying again at t = {back_at_t:.2f} s; it said: {said}")
    assert_stopped_by_the_test(p, code, stopped_at_t)
    with np.load(p.out / "trajectory.npz") as traj:
        err = formation_errors({k: traj[k] for k in ("p", "p0", "offsets")})
    print(f"robot 5 final formation error {err[-1, 4]:.3f} m (worst robot {err[-1].max():.3f} m)")
    measured("docker-lease-cut", load1=os.getloadavg()[0], cut_s=cut_s, back_at_t=back_at_t, stopped_at_t=stopped_at_t,
             err5_final_m=float(err[-1, 4]), worst_final_m=float(err[-1].max()))
    # Cut off, the agent has lost its router (and with it the world): it says so, and that it is back.
    assert any("lost every router" in line or "lost the world" in line for line in said), said
    assert any("reached the swarm again" in line or "the world is back" in line for line in said), said
    # Back in formation: 0.008-0.058 m in 7 runs of LEASE_RUN_S at load 18-30 (MEASURED
    # docker-lease-cut; 11 s after it was back it was 0.02 m: stopped LEASE_SETTLE_S after); stopped
    # so, 0.004-0.109 m in 20 runs at load 8-22 (stopped at t = 34.9-62.9 s); 0.5 m is 4.6 x the worst. Left behind, held still while the leader climbs
    # at 1 m/s, it is metres off (3.3 and 31 m in the runs of 45 s that ended before it was back).
    assert err[-1, 4] <= 0.5
