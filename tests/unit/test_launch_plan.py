"""The launcher's plan, read whole without starting anything (fxswarm/launch/plan.py)."""

from __future__ import annotations

import json
import sys

import pytest

from fxswarm.core.scenario import load
from fxswarm.faults.plan import resolve
from fxswarm.launch.plan import Request, plan_launch
from fxswarm.runtime.router import router_settings
from fxswarm.runtime.tls import files_for

from support import PAPER_FAST


def plan_of(tmp_path, ports=(7001,), faults=(), **options):
    sc = load(PAPER_FAST)
    req = Request(str(PAPER_FAST), tmp_path / "run", **options)
    return plan_launch(req, sc, resolve(sc, faults), list(ports), pid=4242), sc


def argv_value(argv, flag):
    return [argv[k + 1] for k, a in enumerate(argv) if a == flag]


def test_the_plan_lists_every_process_in_start_order_and_starts_or_writes_nothing(tmp_path):
    plan, sc = plan_of(tmp_path)
    names = [c.name for c in plan.children]
    assert names == ["router", "logger", "leader", *[f"agent-{r.id}" for r in sc.robots], "world"]
    assert not (tmp_path / "run").exists()  # pure: the files are written by whoever carries it out
    assert plan.swarm == f"{sc.name}-4242" and plan.topology == "mesh" and plan.endpoint == "tcp/127.0.0.1:7001"
    router = plan.children[0].argv
    assert router[:4] == (sys.executable, "-m", "fxswarm.cli", "router")
    assert argv_value(router, "--listen") == ["tcp/127.0.0.1:7001"] and "--connect" not in router
    agent = plan.children[3].argv
    assert agent[3:5] == ("agent", str(PAPER_FAST)) and argv_value(agent, "--id") == ["1"]
    assert argv_value(agent, "--mode") == ["peer"] and argv_value(agent, "--fault-plan") == [
        str(tmp_path / "run" / "fault-plan.json")]
    assert plan.children[-1].log_path == tmp_path / "run" / "logs" / "world.log"
    assert list(plan.files) == [tmp_path / "run" / "fault-plan.json"]


def test_each_process_lists_the_routers_from_its_own_turn_and_the_routers_mesh(tmp_path):
    plan, sc = plan_of(tmp_path, ports=(7001, 7002), topology="routed")
    a, b = "tcp/127.0.0.1:7001", "tcp/127.0.0.1:7002"
    routers = {c.name: c.argv for c in plan.children if c.role == "router"}
    assert argv_value(routers["router"], "--connect") == [b] and argv_value(routers["router-1"], "--connect") == [a]
    agents = {c.ident: c.argv for c in plan.children if c.role == "agent"}
    assert argv_value(agents[1], "--connect") == [b, a] and argv_value(agents[2], "--connect") == [a, b]
    assert plan.options.mode == "client"


def test_the_official_router_gets_the_config_fxswarm_router_builds(tmp_path):
    keys = tmp_path / "keys"
    plan, sc = plan_of(tmp_path, ports=(7001, 7002), topology="routed", secure=str(keys), zenohd="zenohd --x")
    run = tmp_path / "run"
    conf = run / "router-1.zenohd.json5"
    assert plan.children[1].argv == ("zenohd", "--x", "-c", str(conf))
    access = json.loads(plan.files[run / "access.json"])
    expected = router_settings(["tls/127.0.0.1:7002"], False, files_for(keys, "router"), access,
                               ["tls/127.0.0.1:7001"])
    assert json.loads(plan.files[conf]) == expected
    assert plan.options.tls == files_for(keys, "observer") and plan.options.access is None  # routed


def test_a_restart_in_the_fault_plan_makes_the_world_hold_it_and_a_freeze_makes_the_run_routed(tmp_path):
    plan, _ = plan_of(tmp_path, faults=("kill agent:2 at=1 restart=3",))
    assert "--hold-restarts" in plan.children[-1].argv and plan.topology == "mesh"
    plan, _ = plan_of(tmp_path, faults=("freeze agent:2 at=1 thaw=3",))
    assert plan.topology == "routed"


def test_options_that_do_not_go_together_are_refused_in_the_plan(tmp_path):
    with pytest.raises(ValueError, match="--audit"):
        plan_of(tmp_path, secure="keys", audit=True, topology="mesh")
    with pytest.raises(ValueError, match="topology"):
        plan_of(tmp_path, topology="star")


def test_poll_only_reports_a_dead_router_and_supervise_starts_it_again(tmp_path):
    import subprocess

    from fxswarm.launch.processes import Child
    from fxswarm.launch.swarm import Swarm

    swarm = Swarm(str(PAPER_FAST), tmp_path, logger=False)
    world = swarm.processes.add(Child("world", "world", 0, [sys.executable, "-c", "import sys; sys.stdin.read()"],
                                      tmp_path / "world.log"))
    router = swarm.processes.add(Child("router", "router", 0, [sys.executable, "-c", "import time; time.sleep(60)"],
                                       tmp_path / "router.log"))
    world.popen = subprocess.Popen(world.argv, stdin=subprocess.PIPE)
    router.popen = subprocess.Popen([sys.executable, "-c", "pass"])
    router.popen.wait()
    dead = router.popen
    try:
        deaths = swarm.poll(0)
        assert [(d.child.name, d.restarted) for d in deaths] == [("router", False)]
        assert router.popen is dead and swarm.router_restarts == 0  # poll started nothing
        assert swarm.poll(0) == []  # each death once
        assert [d.restarted for d in swarm.supervise(deaths)] == [True]
        assert router.popen is not dead and router.running() and swarm.router_restarts == 1
    finally:
        world.popen.stdin.close()
        how = swarm.stop(budget=2.0)
    assert how["router"] == "SIGTERM" and not router.running() and not world.running()
