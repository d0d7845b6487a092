"""The law API (issue 27): a user's law beside a scenario, the built-ins through the same path,
the refusals before anything starts, and a law that fails at run time.

The example law is ``configs/examples/tether/tether.py``; each test copies it (or a law of its
own, under a module name of its own: a process imports a module once) beside a scenario."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fxswarm.core.laws import LawError, registered_laws, resolve_law
from fxswarm.core.paper_law import BUILTIN_LAWS, BehaviouralLaw
from fxswarm.core.scenario import ScenarioError, load, parse
from fxswarm.launch.sim import Simulation
from fxswarm.study.variants import variant_toml
from fxswarm.testing import dump_toml

ROOT = Path(__file__).resolve().parents[2]
PAPER_FAST = ROOT / "configs" / "paper-fast.toml"
EXAMPLE = ROOT / "configs" / "examples" / "tether"


def scenario_beside(folder: Path, law: str | None, duration: float = 2.0, params: dict | None = None,
                    name: str = "case", **tables) -> Path:
    """paper-fast with ``[controller] law`` (and params), written into ``folder``."""
    data = tomllib.loads(PAPER_FAST.read_text())
    data["scenario"]["duration"] = duration
    if law is not None:
        data["controller"] = {"law": law} | ({"params": params} if params is not None else {})
    for key, value in tables.items():
        data[key] = value
    path = folder / f"{name}.toml"
    path.write_text(dump_toml(data))
    return path


def tether_beside(folder: Path, duration: float, name: str = "case", **tables) -> Path:
    shutil.copy(EXAMPLE / "tether.py", folder / "tether.py")
    example = tomllib.loads((EXAMPLE / "tether.toml").read_text())["controller"]
    return scenario_beside(folder, example["law"], duration, example["params"], name, **tables)


# --- the user's law, flown by fxswarm sim, against the same law written in matrix form ------------


def tether_in_matrix_form(sc, kc: float, kf: float, ka: float) -> tuple[np.ndarray, np.ndarray]:
    """The Tether law for the whole swarm at once (positions, estimates: (ticks, n, 3)), written
    independently of fxswarm's nodes: the graph as H = L + diag(b), the world's sensing as a
    distance matrix to the obstacles and the other robots."""
    n, dt = sc.n, sc.dt
    H = np.diag(sc.a.sum(axis=1) + sc.b) - sc.a
    p = np.array([r.position for r in sc.robots], dtype=float)
    ph = np.array([r.estimate for r in sc.robots], dtype=float)
    v = np.zeros((n, 3))
    ps, phs = [], []
    for k in range(sc.ticks):
        t = k * dt
        ps.append(p.copy())
        phs.append(ph.copy())
        p0 = sc.leader.position(t)
        offsets = np.array([r.offset.position(t) for r in sc.robots])
        rates = np.array([r.offset.velocity(t) for r in sc.robots])
        dph = kc * (sc.b[:, None] * p0[None, :] - H @ ph)
        vel = dph + rates - kf * (p - ph - offsets)
        obstacles = np.array([o.position(t) for o in sc.obstacles]).reshape(-1, 3)
        objects = np.concatenate([obstacles, p])
        dist = np.linalg.norm(p[:, None, :] - objects[None, :, :], axis=2)
        dist[np.arange(n), len(obstacles) + np.arange(n)] = np.inf
        nearest = objects[dist.argmin(axis=1)]
        u = p - nearest
        r = np.linalg.norm(u, axis=1)
        inside = (r > 0) & (r < sc.d)
        vel[inside] += ka * ((sc.d - r[inside]) / r[inside])[:, None] * u[inside]
        p = p + dt * vel
        ph = ph + dt * dph
        v = vel
    del v
    return np.array(ps), np.array(phs)


def test_a_law_beside_the_scenario_flies_as_its_matrix_form(tmp_path):
    """Tether (configs/examples) in `fxswarm sim`, robots passing obstacles and one another,
    against an independent vectorised implementation: max |dp| under 1e-9."""
    sc = load(tether_beside(tmp_path, duration=12.0))
    assert sc.law == "tether:Tether" and sc.law_params == {"kc": 8.0, "kf": 2.0, "ka": 2.0}
    sim = Simulation(sc)
    summary = sim.run()
    traj = sim.trajectory()
    p, ph = tether_in_matrix_form(sc, **sc.law_params)
    assert traj["p"].shape == p.shape
    assert np.abs(traj["p"] - p).max() < 1e-9
    assert np.abs(traj["ph"] - ph).max() < 1e-9
    assert traj["avoid_active"].any()  # the avoidance spring acted (an obstacle at z = 7 m)
    assert summary["law"] == {"name": "tether:Tether", "errors": {}}
    # and it is not the paper's law: the same scenario without `law` flies differently
    paper = Simulation(load(scenario_beside(tmp_path, None, 12.0, name="paper")))
    paper.run()
    assert np.abs(paper.trajectory()["p"] - traj["p"]).max() > 0.1


def test_fxswarm_sim_on_the_shipped_example(tmp_path):
    """The example as shipped, from another working directory: its folder is on the import path."""
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "fxswarm.cli", "sim", str(EXAMPLE / "tether.toml"), "--quiet",
                           "--out", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "summary.json").read_text())["law"]["name"] == "tether:Tether"


# --- the built-ins, through the same API ----------------------------------------------------------


def test_the_builtins_are_registered_entry_points_of_one_class():
    registered = registered_laws()
    for name in BUILTIN_LAWS:
        assert resolve_law(name) is BehaviouralLaw, name
        assert registered[name] == "fxswarm.core.paper_law:BehaviouralLaw"


def run(sc) -> dict:
    sim = Simulation(sc)
    sim.run()
    return sim.trajectory()


@pytest.mark.parametrize("name", BUILTIN_LAWS)
def test_a_builtin_name_flies_what_the_legacy_keys_fly(name):
    """`law = "asymptotic+feedforward"` is the sweep's variant of that name, bit for bit; on the
    paper's gains `law = "fixed-time"` is no `law` at all."""
    base = tomllib.loads(PAPER_FAST.read_text())
    base["scenario"]["duration"] = 1.0
    legacy = parse(variant_toml(base, name), "legacy")
    named = parse(dict(base, controller={"law": name}), "named")
    assert named.law == legacy.law == name
    assert (named.formation, named.estimator, named.tracking) == (legacy.formation, legacy.estimator, legacy.tracking)
    a, b = run(named), run(legacy)
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    if name == "fixed-time":
        plain = run(parse(base, "plain"))
        assert all(np.array_equal(a[k], plain[k]) for k in a)


def test_a_builtin_name_conflicting_with_the_legacy_keys_is_refused():
    base = tomllib.loads(PAPER_FAST.read_text())
    with pytest.raises(ScenarioError, match=r"x: controller\.variant: expected 'asymptotic' or nothing with law = "
                                            r"'asymptotic', got 'fixed-time'"):
        parse(dict(base, controller={"law": "asymptotic", "variant": "fixed-time"}), "x")
    with pytest.raises(ScenarioError, match=r"x: estimator\.tracking: expected 'feedforward' or nothing"):
        parse(dict(base, controller={"law": "fixed-time+feedforward"}, estimator={"tracking": "paper"}), "x")
    with pytest.raises(ScenarioError, match=r"x: controller\.law: BehaviouralLaw\(params, robot_id=1\): the built-in "
                                            r"law takes no parameters"):
        parse(dict(base, controller={"law": "fixed-time", "params": {"kf": 1.0}}), "x")


# --- refused before anything starts ---------------------------------------------------------------

NO_METHOD = "class Half:\n    def __init__(self, params, robot_id, scenario): pass\n    def velocity(self, view, r): return r\n"
RAISING_INIT = ("class Picky:\n    def __init__(self, params, robot_id, scenario):\n"
                "        if params.get('kf', 0) <= 0: raise ValueError(f'kf must be > 0, got {params.get(\"kf\")}')\n"
                "    def estimate_rate(self, view): return [0, 0, 0]\n"
                "    def velocity(self, view, r): return [0, 0, 0]\n")
BROKEN_MODULE = "import numpy as np\ndef velocity(:\n"


@pytest.mark.parametrize("law, module, params, cause", [
    ("nosuchlaw:Tether", None, None,
     r"cannot import 'nosuchlaw' \(looked in .* and the installed packages\): ModuleNotFoundError"),
    ("brokenlaw:Law", ("brokenlaw", BROKEN_MODULE), None, r"cannot import 'brokenlaw': SyntaxError"),
    ("halflaw:Half", ("halflaw", NO_METHOD), None, r"class Half lacks the method estimate_rate"),
    ("halflaw2:Other", ("halflaw2", NO_METHOD), None, r"module 'halflaw2' has no 'Other'"),
    ("pickylaw:Picky", ("pickylaw", RAISING_INIT), {"kf": -1.0},
     r"Picky\(params, robot_id=1\) raised ValueError: kf must be > 0, got -1.0"),
    ("fixed-tim", None, None, r"'fixed-tim' is neither a registered law \(asymptotic, .*\) nor module:Class"),
])
def test_a_law_that_cannot_fly_is_refused_with_file_field_and_cause(tmp_path, law, module, params, cause):
    if module is not None:
        (tmp_path / f"{module[0]}.py").write_text(module[1])
    path = scenario_beside(tmp_path, law, params=params)
    with pytest.raises(ScenarioError, match=rf"^{path}: controller\.law: {cause}"):
        load(path)


def test_fxswarm_sim_and_run_exit_2_before_any_process_starts(tmp_path):
    (tmp_path / "pickylaw.py").write_text(RAISING_INIT)
    path = scenario_beside(tmp_path, "pickylaw:Picky", params={"kf": 0})
    for command in (["sim", str(path)], ["run", str(path), "--out", str(tmp_path / "run"), "--no-logger"]):
        proc = subprocess.run([sys.executable, "-m", "fxswarm.cli", *command], capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 2, (command, proc.stderr)
        assert f"{path}: controller.law: Picky(params, robot_id=1) raised ValueError: kf must be > 0" in proc.stderr
    assert not (tmp_path / "run" / "logs").exists()  # nothing was started


def test_resolve_law_is_the_check_a_command_runs_on_a_name(tmp_path):
    (tmp_path / "checked_law.py").write_text(NO_METHOD.replace("Half", "Fine").replace(
        "    def velocity", "    def estimate_rate(self, view): return [0, 0, 0]\n    def velocity"))
    assert resolve_law("checked_law:Fine", tmp_path).__name__ == "Fine"
    with pytest.raises(LawError, match="neither a registered law"):
        resolve_law("tether")


# --- a law that fails at run time ------------------------------------------------------------------

#: A law that fails on some robots at some times (copied beside a scenario under a module name of its own).
FLAKY = (Path(__file__).parent / "data" / "flaky_law.py").read_text()


def flaky_sim(tmp_path, **tables):
    (tmp_path / "flakylaw.py").write_text(FLAKY)
    sc = load(scenario_beside(tmp_path, "flakylaw:Flaky", duration=1.5, **tables))
    sim = Simulation(sc)
    return sc, sim, sim.run()


def test_a_failing_law_stops_the_robot_keeps_its_estimate_and_is_counted(tmp_path):
    sc, sim, summary = flaky_sim(tmp_path)
    traj = sim.trajectory()
    dt = sc.dt
    assert len(traj["t"]) == sc.ticks  # the run went on to the end
    errors = summary["law"]["errors"]
    assert errors["2"] == {"ticks": 30, "first": "velocity: RuntimeError: robot 2 gave up at t = 0.50"}
    assert errors["3"] == {"ticks": 50, "first": "estimate_rate: ValueError: expected 3 finite numbers, "
                                                "got [nan, 0.0, 0.0]"}
    assert errors["5"] == {"ticks": 10, "first": "velocity: ValueError: expected 3 finite numbers, got [1.0, 2.0]"}
    assert set(errors) == {"2", "3", "5"}
    assert summary["faults"]["degraded_ticks"]["law_error"] == {"2": 30, "3": 50, "5": 10}
    k0, k1 = round(0.5 / dt), round(0.8 / dt)
    assert np.all(traj["v"][k0:k1, 1] == 0.0)  # robot 2: zero velocity while its law fails
    assert np.all(traj["p"][k0:k1 + 1, 1] == traj["p"][k0, 1])
    assert np.all(traj["ph"][k0:k1, 1] == traj["ph"][k0, 1])  # and its estimate kept
    assert np.any(traj["v"][k1:, 1] != 0.0)  # then it flies again
    k = round(1.0 / dt)
    assert np.all(traj["ph"][k:, 2] == traj["ph"][k, 2]) and np.all(np.isfinite(traj["p"]))
    assert math.isfinite(summary["formation_error_final_m"])


def test_a_numpy_law_that_returns_a_list_or_a_tuple_is_taken_as_is(tmp_path):
    """3 numbers in any sequence: a tuple of ints flies as floats."""
    (tmp_path / "tuplelaw.py").write_text(
        "class Still:\n    def __init__(self, params, robot_id, scenario): pass\n"
        "    def estimate_rate(self, view): return (0, 0, 1)\n"
        "    def velocity(self, view, rate): return (0, 0, int(rate[2]))\n")
    sim = Simulation(load(scenario_beside(tmp_path, "tuplelaw:Still", duration=0.5)))
    summary = sim.run()
    traj = sim.trajectory()
    assert summary["law"]["errors"] == {}
    assert np.allclose(traj["v"][:, :, 2], 1.0) and np.all(traj["v"][:, :, :2] == 0.0)


# --- the sweep: a user's law as a variant beside the built-ins ---------------------------------------


def test_sweep_flies_a_users_law_beside_the_builtins_in_worker_processes(tmp_path):
    from fxswarm.study.sweep import plan, run_sweep

    base = load(tether_beside(tmp_path, duration=5.0))
    rows = run_sweep(plan(base, [1.0, 10.0], ["fixed-time", "tether:Tether"], duration=6.0), workers=2)
    assert [(r["variant"], r["law"], r["scale"]) for r in rows] == [
        ("fixed-time", "fixed-time", 1.0), ("fixed-time", "fixed-time", 10.0),
        ("tether:Tether", "tether:Tether", 1.0), ("tether:Tether", "tether:Tether", 10.0)]
    # the user's row is that law's run: the same case flown here, in this process
    raw, label, _, _, folder = plan(base, [10.0], ["tether:Tether"], duration=6.0)[0]
    sim = Simulation(parse(raw, label, folder))
    summary = sim.run()
    assert rows[3]["formation_error_final_m"] == summary["formation_error_final_m"]
    assert rows[1]["formation_error_final_m"] != rows[3]["formation_error_final_m"]


def test_sweep_refuses_a_law_that_cannot_fly_before_it_starts(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "fxswarm.cli", "sweep", str(PAPER_FAST), "--variants",
                           "fixed-time,nosuch:Law", "--out", str(tmp_path / "out")], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert f"{PAPER_FAST}: controller.law: cannot import 'nosuch'" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_an_observer_loads_a_scenario_whose_law_it_cannot_import(tmp_path):
    """`fxswarm attach` fetches the scenario's text from the router: it flies nothing, so the
    law module, which stays with the robots, is not needed there."""
    path = scenario_beside(tmp_path, "lawelsewhere:Law")
    with pytest.raises(ScenarioError, match="controller.law: cannot import 'lawelsewhere'"):
        load(path)
    assert load(path, check_law=False).law == "lawelsewhere:Law"


def test_the_speed_limit_is_the_nodes_for_every_law(tmp_path):
    """[scenario] v_max scales any law's command down to the limit (the built-in's as before)."""
    paths = {"tether": tether_beside(tmp_path, duration=1.0, name="limited")}
    for name, path in paths.items():
        data = tomllib.loads(path.read_text())
        data["scenario"]["v_max"] = 0.5
        path.write_text(dump_toml(data))
    base = tomllib.loads(PAPER_FAST.read_text())
    base["scenario"] |= {"duration": 1.0, "v_max": 0.5}
    # The user's law, and each built-in by its name (the entry points fxswarm.laws).
    from importlib.metadata import entry_points

    built_in = sorted(e.name for e in entry_points(group="fxswarm.laws"))
    assert len(built_in) == 6, built_in
    for sc in (load(paths["tether"]), *(parse(base | {"controller": {"law": law}}, law) for law in built_in)):
        sim = Simulation(sc)
        summary = sim.run()
        speed = np.linalg.norm(sim.trajectory()["v"], axis=2)
        assert summary["speed_limited_ticks"] > 0, sc.law
        assert speed.max() <= 0.5 * (1 + 1e-12) and speed.max() > 0.49, sc.law
