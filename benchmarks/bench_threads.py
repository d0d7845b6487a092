"""Where the CPU of a lock-step tick goes: per role and per thread, runtime against its floor.

    python benchmarks/bench_threads.py [CONFIG] [--short 500] [--long 3000] [--repeat 2]
        [--out benchmarks/results/threads.json]

Runs ``fxswarm run CONFIG --clock lockstep --no-logger`` and the floor
(benchmarks/bench_floor.py) each twice, ``--short`` and ``--long`` ticks,
interleaved (runtime short, runtime long, floor short, floor long, then
again). Every 0.2 s it reads the CPU time (user + system) of every thread
of every process from ``/proc``; a thread's total is its last reading. The
difference long - short, divided by the ticks between them, is the CPU per
tick with start-up and shut-down cancelled out. Threads are grouped by role
(world, leader, agent: all agents summed, router) and by kind: ``python``
(the main thread and the Python threads zenoh-python runs each subscriber's
callback on: the node, the codec, the hand-over to Python), ``rx``/``tx``
(Zenoh's receive and send threads), ``net``/``acc``/other (Zenoh's runtime).
Medians over ``--repeat``; the load average is recorded with each run.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import machine, write_json  # noqa: E402  (a sibling script)

HZ = os.sysconf("SC_CLK_TCK")


def _children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(x) for x in f.read().split()]
    except OSError:
        pass
    return out


def _descendants(pid: int) -> list[int]:
    found, todo = [], [pid]
    while todo:
        kids = _children(todo.pop())
        found += kids
        todo += kids
    return found


def _role(cmdline: str) -> str | None:
    for role in ("world", "leader", "agent", "router"):
        if f"fxswarm.cli {role}" in cmdline or f"--role {role}" in cmdline:
            return role
    return None


def _kind(comm: str) -> str:
    head = comm.split("-")[0]
    return head if head in ("rx", "tx", "net", "acc") else ("python" if comm.startswith("python") else "other")


def _switches(pid: int, tid: str) -> int:
    """Context switches of one thread so far, voluntary (it blocked) and not (it was preempted)."""
    total = 0
    for line in Path(f"/proc/{pid}/task/{tid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name.endswith("ctxt_switches"):
            total += int(value)
    return total


def cpu_by_thread(argv: list[str], env: dict | None = None) -> tuple[dict[str, float], dict[str, int]]:
    """Run ``argv``; return CPU s per ``role/kind`` summed over the run's processes' threads, and
    their context switches per role."""
    last: dict[tuple[int, int], tuple[str, str, float, int]] = {}
    roles: dict[int, str | None] = {}
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, text=True)
    while proc.poll() is None:
        for pid in _descendants(proc.pid):
            if pid not in roles:
                try:
                    roles[pid] = _role(Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " "))
                except OSError:
                    continue
            role = roles[pid]
            if role is None:
                continue
            try:
                tids = os.listdir(f"/proc/{pid}/task")
            except OSError:
                continue
            for tid in tids:
                try:
                    stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
                    switches = _switches(pid, tid)
                except OSError:
                    continue
                comm = stat[stat.index("(") + 1:stat.rindex(")")]
                fields = stat[stat.rindex(")") + 2:].split()
                last[(pid, int(tid))] = (role, _kind(comm), (int(fields[11]) + int(fields[12])) / HZ, switches)
        time.sleep(0.2)
    err = proc.stderr.read()
    if proc.returncode != 0:
        raise RuntimeError(f"{argv[:4]} failed ({proc.returncode}): {err[-1500:]}")
    cpu_s: dict[str, float] = collections.defaultdict(float)
    switched: dict[str, int] = collections.defaultdict(int)
    for role, kind, cpu, switches in last.values():
        cpu_s[f"{role}/{kind}"] += cpu
        switched[role] += switches
    return dict(cpu_s), dict(switched)


def runtime_argv(config: Path, folder: Path, ticks: int) -> list[str]:
    from fxswarm.testing import scenario_with

    sc = scenario_with(config, folder, duration=ticks * 0.01)
    return [sys.executable, "-m", "fxswarm.cli", "run", str(sc), "--clock", "lockstep", "--no-logger", "--quiet",
            "--out", str(folder / f"run-{ticks}")]


def floor_argv(config: Path, ticks: int) -> list[str]:
    code = ("import sys, json; sys.path.insert(0, 'benchmarks'); from bench_floor import floor_lockstep; "
            f"print(json.dumps(floor_lockstep({str(config)!r}, {ticks})))")
    return [sys.executable, "-c", code]


def per_tick_us(short: dict[str, float], long: dict[str, float], ticks: int, us: float = 1e6) -> dict[str, float]:
    """``long - short`` per key, per tick, times ``us`` (us per unit of the readings; 1 for counts)."""
    keys = sorted(set(short) | set(long))
    return {k: round(us * (long.get(k, 0.0) - short.get(k, 0.0)) / ticks, 1) for k in keys}


def add_short_long_arguments(p: argparse.ArgumentParser, out: str) -> None:
    """The arguments of a short-against-long benchmark (this one and bench_perf.py)."""
    p.add_argument("config", nargs="?", default=str(ROOT / "configs" / "paper-fast.toml"))
    p.add_argument("--short", type=int, default=500)
    p.add_argument("--long", type=int, default=3000)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / out))


def short_and_long(a: argparse.Namespace, measure):
    """Runtime and floor, ``a.short`` and ``a.long`` ticks each, interleaved ``a.repeat`` times:
    yields ``(round, "runtime"|"floor", {ticks: measure(argv, folder)})``."""
    config = Path(a.config).resolve()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeat):
            for name in ("runtime", "floor"):
                got = {}
                for n in (a.short, a.long):
                    argv = runtime_argv(config, Path(tmp), n) if name == "runtime" else floor_argv(config, n)
                    got[n] = measure(argv, Path(tmp))
                yield i, name, got


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_short_long_arguments(p, "threads.json")
    a = p.parse_args()
    ticks = a.long - a.short
    result: dict = {"machine": machine(), "config": str(Path(a.config).resolve()), "short": a.short,
                    "long": a.long, "runtime": [], "floor": []}
    for i, name, got in short_and_long(a, lambda argv, _folder: cpu_by_thread(argv)):
        (cpu_short, sw_short), (cpu_long, sw_long) = got[a.short], got[a.long]
        row = {"us_per_tick": per_tick_us(cpu_short, cpu_long, ticks),
               "switches_per_tick": per_tick_us(sw_short, sw_long, ticks, us=1), "load_avg": os.getloadavg()[0]}
        for what in ("us_per_tick", "switches_per_tick"):
            row[what]["total"] = round(sum(row[what].values()), 1)
        result[name].append(row)
        print(name, i, json.dumps(row), file=sys.stderr)
    for what in ("us_per_tick", "switches_per_tick"):
        result[f"median_{what}"] = {
            name: {k: statistics.median(r[what].get(k, 0.0) for r in result[name]) for k in result[name][0][what]}
            for name in ("runtime", "floor")}
    write_json(a.out, result)
    print(json.dumps({k: result[k] for k in ("median_us_per_tick", "median_switches_per_tick")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
