"""`fxswarm campaign` as a user runs it: real worker processes, a real Dask scheduler and workers,
a campaign killed part-way and run again, a recorded run replayed alone with its command line,
runs confirmed as a distributed lock-step swarm over Zenoh."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fxswarm.launch.launcher import free_port
from fxswarm.study.campaign import outcome
from fxswarm.study.campaign_plan import Criteria

from support import PAPER_FAST, port_nobody_listens_on

BIN = Path(sys.executable).parent
FXSWARM = str(BIN / "fxswarm")


def campaign_argv(out: Path, *extra: str, duration: float = 1.0, losses: str = "0,0.4") -> list[str]:
    return [FXSWARM, "campaign", str(PAPER_FAST), "--out", str(out),
            "--fault", "agent:*->agent:* drop={loss} delay={delay}", "--grid", f"loss={losses}",
            "--grid", "delay=0,0.05", "--grid", f"scenario.duration={duration}", "--laws", "fixed-time,asymptotic",
            "--final-error", "0.5", *extra]


def run_campaign(out: Path, *extra: str, timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    proc = subprocess.run(campaign_argv(out, *extra, **kw), capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    return proc


def records(out: Path) -> list[dict]:
    text = (out / "runs.jsonl").read_text()
    assert text.endswith("\n")
    return [json.loads(line) for line in text.splitlines()]


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (from /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def parent_of(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def wait_gone(pids: list[int], timeout: float = 10.0) -> None:
    """Wait until none of ``pids`` is alive (a zombie counts as gone), or fail naming them."""
    def alive(pid: int) -> bool:
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False

    deadline = time.monotonic() + timeout
    while any(alive(p) for p in pids):
        assert time.monotonic() < deadline, f"processes {[p for p in pids if alive(p)]} are still running"
        time.sleep(0.05)


def test_a_recorded_run_replayed_alone_with_its_command_line_gives_the_same_outcome(tmp_path):
    out = tmp_path / "c"
    run_campaign(out, "--seeds", "1", "--workers", "2", losses="0.4")
    recs = records(out)
    assert len(recs) == 4 and all(r["status"] == "done" for r in recs)
    criteria = Criteria(**json.loads((out / "campaign.json").read_text())["criteria"])
    for rec in (recs[0], recs[-1]):
        argv = rec["argv"]
        assert argv[:2] == ["fxswarm", "sim"] and rec["command"].startswith("fxswarm sim ")
        replay = subprocess.run([FXSWARM, *argv[1:]], capture_output=True, text=True, timeout=120,
                                stdin=subprocess.DEVNULL)
        assert replay.returncode == 0, replay.stderr
        summary = json.loads((Path(argv[argv.index("--out") + 1]) / "summary.json").read_text())
        again = outcome(summary, criteria)
        assert again == {k: rec[k] for k in ("success", "failed", "metrics")}
        assert again["metrics"]["messages"]["dropped"] > 0  # the faults acted


@contextlib.contextmanager
def campaign_under_way(out: Path, lines: int):
    """A 16-run campaign started as a process (its own session), once ``lines`` runs are in
    runs.jsonl (polled, with a timeout); whatever the test leaves running is killed after it."""
    proc = subprocess.Popen(campaign_argv(out, "--seeds", "2", "--workers", "2", duration=2.0),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    runs = out / "runs.jsonl"
    end = time.monotonic() + 180
    try:
        while not (runs.is_file() and runs.read_text().count("\n") >= lines):
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < end, f"fewer than {lines} runs finished within 180 s"
            time.sleep(0.02)
        yield proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
        proc.stderr.close()


def test_a_campaign_killed_part_way_and_run_again_has_every_run_exactly_once(tmp_path):
    out = tmp_path / "c"
    with campaign_under_way(out, 2) as proc:
        workers = descendants(proc.pid)
        proc.send_signal(signal.SIGKILL)  # the campaign dies at once: no clean-up of its own
        proc.wait(10)
    wait_gone(workers)  # its workers see their parent gone and leave on their own
    before = records(out)
    assert 2 <= len(before) < 16, "the campaign was not killed part-way"
    again = run_campaign(out, "--seeds", "2", "--workers", "2", duration=2.0)
    assert f"{len(before)} already done, {16 - len(before)} to run" in again.stderr
    after = records(out)
    assert after[:len(before)] == before  # nothing finished was lost or rewritten
    ids = [r["id"] for r in after]
    assert len(ids) == 16 and len(set(ids)) == 16
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["complete"] and doc["totals"]["runs"] == 16


def test_ctrl_c_stops_the_campaign_and_its_workers_keeping_whole_lines(tmp_path):
    out = tmp_path / "c"
    with campaign_under_way(out, 1) as proc:
        workers = descendants(proc.pid)
        assert workers, "no worker processes"
        proc.send_signal(signal.SIGINT)
        code = proc.wait(30)
        err = proc.stderr.read().decode()
    assert code == 130 and "interrupted" in err, err
    wait_gone(workers)
    recs = records(out)
    assert 1 <= len(recs) < 16
    doc = json.loads((out / "campaign.json").read_text())  # written on the way out, marked incomplete
    assert not doc["complete"] and doc["totals"]["runs"] == len(recs)


def test_a_killed_worker_ends_the_campaign_keeping_every_finished_run_and_the_rest_runs_again(tmp_path):
    out = tmp_path / "c"
    with campaign_under_way(out, 1) as proc:
        below = descendants(proc.pid)
        (server,) = [p for p in below if b"forkserver" in Path(f"/proc/{p}/cmdline").read_bytes()
                     and parent_of(p) == proc.pid]
        workers = [p for p in below if parent_of(p) == server]  # forked from the workers' fork server
        assert len(workers) == 2, workers
        os.kill(workers[0], signal.SIGKILL)  # as the kernel's OOM killer would
        code = proc.wait(60)
        err = proc.stderr.read().decode()
    assert code == 1 and "worker process died" in err, err
    wait_gone(workers)
    before = records(out)
    assert 1 <= len(before) < 16
    run_campaign(out, "--seeds", "2", "--workers", "2", duration=2.0)
    after = records(out)
    assert after[:len(before)] == before
    assert sorted({r["id"] for r in after}) == sorted(r["id"] for r in after) and len(after) == 16


@pytest.fixture
def dask_cluster(tmp_path):
    """A real Dask scheduler and two single-threaded workers on 127.0.0.1, torn down after the test.
    The workers run in a folder of their own, as on another machine: the campaign's folder is
    not theirs, so what they import must reach them through the scheduler."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    elsewhere = tmp_path / "workers-home"
    elsewhere.mkdir()
    procs = []

    def start(name: str, argv: list[str]) -> None:
        with open(logs / f"{name}.log", "wb") as log:
            procs.append(subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                          start_new_session=True, cwd=elsewhere))

    try:
        start("scheduler", [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                            "--no-dashboard"])
        for k in range(2):
            start(f"worker-{k}", [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--no-nanny",
                                  "--no-dashboard", "--host", "127.0.0.1", "--name", f"w{k}"])
        from distributed import Client

        with Client(address, timeout="60s") as client:  # waits for the scheduler to answer
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        # The workers first, then the scheduler: a worker whose scheduler went first spends its
        # close retrying it (the teardown took 30 s when all three were stopped at once).
        workers, scheduler = procs[1:], procs[:1]
        for group in (workers, scheduler):
            for p in group:
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGTERM)
            for p in group:
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, signal.SIGKILL)
                    p.wait(5)


def executed_on_workers(address: str) -> int:
    """Tasks the cluster's workers have executed so far, by their own count."""
    from distributed import Client

    with Client(address, timeout="60s") as client:
        return sum(client.run(lambda dask_worker: dask_worker.state.executed_count).values())


def test_a_campaign_on_a_dask_cluster_gives_the_same_campaign_json_as_the_local_pool(tmp_path, dask_cluster):
    local, dask = tmp_path / "local", tmp_path / "dask"
    run_campaign(local, "--seeds", "2", "--workers", "2")
    before = executed_on_workers(dask_cluster)
    proc = run_campaign(dask, "--seeds", "2", "--executor", f"dask://{dask_cluster[len('tcp://'):]}")
    assert "to run on dask://" in proc.stderr
    a, b = (local / "campaign.json").read_text(), (dask / "campaign.json").read_text()
    assert json.loads(a)["totals"]["runs"] == 16
    assert a == b
    assert sorted(r["id"] for r in records(dask)) == sorted(r["id"] for r in records(local))
    # The workers really ran them, by their own count (a silent local fallback gives the same ids).
    assert executed_on_workers(dask_cluster) - before >= 16


STILL = """
class Still:
    \"\"\"A user's law that holds its robot still.\"\"\"

    def __init__(self, params, robot_id, scenario):
        pass

    def estimate_rate(self, view):
        return (0.0, 0.0, 0.0)

    def velocity(self, view, estimate_rate):
        return (0.0, 0.0, 0.0)
"""


def test_a_users_law_modules_beside_the_scenario_are_sent_to_the_dask_workers(tmp_path, dask_cluster):
    """A law file and a law package that only this machine has reach every Dask worker (a real
    cluster would not see the campaign's folder): the runs fly them, and each worker holds them."""
    config = tmp_path / "paper-fast.toml"
    config.write_text(Path(PAPER_FAST).read_text())
    (tmp_path / "stilllaw.py").write_text(STILL)
    (tmp_path / "stillpkg").mkdir()
    (tmp_path / "stillpkg" / "__init__.py").write_text(STILL)
    out = tmp_path / "c"
    argv = [FXSWARM, "campaign", str(config), "--out", str(out), "--fault", "agent:*->agent:* drop={loss}",
            "--grid", "loss=0,0.4", "--grid", "scenario.duration=0.5", "--laws", "stilllaw:Still,stillpkg:Still",
            "--executor", f"dask://{dask_cluster[len('tcp://'):]}"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    recs = records(out)
    assert sorted(r["law"] for r in recs) == ["stilllaw:Still"] * 2 + ["stillpkg:Still"] * 2
    assert all(r["status"] == "done" and not r["metrics"]["law_errors"] for r in recs), recs
    from distributed import Client

    with Client(dask_cluster, timeout="60s") as client:
        held = client.run(lambda dask_worker: sorted(os.listdir(dask_worker.local_directory)))
    assert len(held) == 2 and all({"stilllaw.py", "stillpkg.zip"} <= set(names) for names in held.values()), held


def test_an_executor_that_does_not_answer_is_refused_in_one_line(tmp_path):
    with port_nobody_listens_on() as port:
        proc = subprocess.run(campaign_argv(tmp_path / "c", "--executor", f"dask://127.0.0.1:{port}"),
                              capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert proc.returncode == 2 and "no Dask scheduler answers there" in proc.stderr, proc.stderr


@pytest.mark.zenoh
def test_confirm_runs_drawn_runs_again_as_a_lockstep_swarm_and_finds_them_equal(tmp_path):
    out = tmp_path / "c"
    proc = run_campaign(out, "--seeds", "1", "--workers", "2", "--confirm", "1", duration=0.5, losses="0.4")
    doc = json.loads((out / "confirm.json").read_text())
    assert doc["confirmed"] == 1 and doc["equal"] == 1, doc
    entry = doc["runs"][0]
    assert entry["command"].startswith("fxswarm run ") and "--clock lockstep" in entry["command"]
    assert (out / "confirm" / entry["id"] / "trajectory.npz").is_file()
    assert "1/1 lock-step runs equal" in proc.stderr


def test_report_draws_the_map_and_distributions_of_a_campaign(tmp_path):
    out = tmp_path / "c"
    run_campaign(out, "--seeds", "1", "--workers", "2", duration=0.5)
    proc = subprocess.run([FXSWARM, "report", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for name in ("success_map.png", "distributions.png", "index.md"):
        assert (out / name).stat().st_size > 0, name
    index = (out / "index.md").read_text()
    assert index.count("\n| fixed-time |") == 4 and index.count("\n| asymptotic |") == 4
    assert "![success_map](success_map.png)" in index


def test_a_scenario_whose_own_law_sits_beside_it_runs_on_dask_workers_in_another_folder(tmp_path, dask_cluster):
    """No --laws: the law the scenario itself names (a module beside the scenario file) reaches
    every worker as a --laws one does; before, every run errored with "cannot import"."""
    home = tmp_path / "mine"
    home.mkdir()
    (home / "stilllaw.py").write_text(STILL)
    config = home / "still.toml"
    config.write_text(Path(PAPER_FAST).read_text() + '\n[controller]\nlaw = "stilllaw:Still"\n')
    out = tmp_path / "c"
    argv = [FXSWARM, "campaign", str(config), "--out", str(out), "--fault", "agent:*->agent:* drop={loss}",
            "--grid", "loss=0,0.4", "--grid", "scenario.duration=0.5",
            "--executor", f"dask://{dask_cluster[len('tcp://'):]}"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    recs = records(out)
    assert [r["law"] for r in recs] == ["stilllaw:Still"] * 2
    assert all(r["status"] == "done" and not r["metrics"]["law_errors"] for r in recs), recs
    from distributed import Client

    with Client(dask_cluster, timeout="60s") as client:
        held = client.run(lambda dask_worker: sorted(os.listdir(dask_worker.local_directory)))
    assert all("stilllaw.py" in names for names in held.values()), held

