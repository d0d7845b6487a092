"""Where one robot's CPU per lock-step tick goes, by library: runtime against its floor (Linux ``perf``).

    python benchmarks/bench_perf.py [CONFIG] [--robot 2] [--short 500] [--long 3000] [--repeat 2]
        [--out benchmarks/results/perf.json]

bench_threads.py splits the CPU by thread; this splits one agent process's CPU by
the library it runs in: the Python interpreter (``libpython``), the kernel (system
calls, wake-ups, TCP), Zenoh (``zenoh.abi3.so``), libc, and the rest (numpy,
msgpack, ...). ``perf record -a -F 999`` samples the machine while robot ``--robot``'s
process lives (then keeps the samples of its threads), in a runtime run (``fxswarm run CONFIG --clock lockstep
--no-logger``) and in a floor run (benchmarks/bench_floor.py), each with
``--short`` and ``--long`` ticks, interleaved; the difference long - short,
divided by the ticks between them, is the CPU per tick with start-up and
shut-down cancelled out (one sample is about 1/999 s of CPU). Medians over
``--repeat``; the load average is recorded with each run.

Needs ``perf`` and permission to sample the whole machine (root, or
``kernel.perf_event_paranoid`` <= 0); says so and exits 2 otherwise.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_io import machine, write_json  # noqa: E402  (sibling scripts)
from bench_threads import (_descendants, _role, add_short_long_arguments, per_tick_us,  # noqa: E402
                          short_and_long)

FREQ = 999  # samples per CPU second
GROUPS = (("libpython", "python"), ("[kernel", "kernel"), ("zenoh", "zenoh"), ("libc.so", "libc"))


def _group(dso: str) -> str:
    for needle, name in GROUPS:
        if needle in dso:
            return name
    return "other"


def _agent_pid(root: int, robot: int) -> int | None:
    """The pid of robot ``robot``'s process under ``root`` (runtime or floor), once it exists."""
    for pid in _descendants(root):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_text().split("\0")
        except OSError:
            continue
        if _role(" ".join(cmd)) == "agent" and "--id" in cmd and cmd[cmd.index("--id") + 1] == str(robot):
            return pid
    return None


def samples_by_group(argv: list[str], robot: int, folder: Path) -> dict[str, int]:
    """Run ``argv`` under a system-wide ``perf record``; samples of robot ``robot``'s process (all
    its threads, also those started after it: ``perf record -p`` would miss Zenoh's) per library."""
    data = folder / "perf.data"
    perf = subprocess.Popen(["perf", "record", "-q", "-a", "-F", str(FREQ), "-o", str(data)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(0.5)  # perf opens its events before the run starts
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        pid, tids = None, set()
        try:
            while pid is None and proc.poll() is None:
                pid = _agent_pid(proc.pid, robot)
                time.sleep(0.01)
            while pid is not None and proc.poll() is None:  # its threads, as they come
                try:
                    tids.update(os.listdir(f"/proc/{pid}/task"))
                except OSError:
                    pass
                time.sleep(0.05)
            err = proc.communicate(timeout=300)[1]
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        if proc.returncode != 0:
            raise RuntimeError(f"{argv[:4]} failed ({proc.returncode}): {err[-1500:]}")
        if pid is None:
            raise RuntimeError(f"{argv[:4]}: robot {robot}'s process never appeared")
    finally:
        perf.send_signal(signal.SIGINT)
        perf.wait(timeout=60)
    # Per sample, its thread and library (perf report's --pid and --tid keep too little here).
    script = subprocess.run(["perf", "script", "-i", str(data), "-F", "tid,ip,dso"], capture_output=True,
                            text=True, check=True).stdout
    data.unlink()
    out: dict[str, int] = collections.Counter()
    for line in script.splitlines():
        f = line.split(maxsplit=2)
        if len(f) == 3 and f[0] in tids:
            out[_group(f[2])] += 1
    return dict(out)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_short_long_arguments(p, "perf.json")
    p.add_argument("--robot", type=int, default=2)
    a = p.parse_args()
    if shutil.which("perf") is None:
        print("bench_perf: needs Linux perf (Debian: apt-get install linux-perf)", file=sys.stderr)
        return 2
    probe = subprocess.run(["perf", "record", "-q", "-a", "-o", os.devnull, "--", "true"], capture_output=True,
                           text=True)
    if probe.returncode != 0:
        print(f"bench_perf: perf cannot record here: {probe.stderr.strip()[-300:]}", file=sys.stderr)
        return 2
    ticks = a.long - a.short
    result: dict = {"machine": machine(), "config": str(Path(a.config).resolve()), "robot": a.robot,
                    "short": a.short, "long": a.long, "unit": "CPU us per tick of one agent process",
                    "runtime": [], "floor": []}
    for i, name, got in short_and_long(a, lambda argv, folder: samples_by_group(argv, a.robot, folder)):
        per_tick = per_tick_us(got[a.short], got[a.long], ticks, us=1e6 / FREQ)
        per_tick["total"] = round(sum(per_tick.values()), 1)
        row = {"us_per_tick": per_tick, "load_avg": round(os.getloadavg()[0], 2)}
        result[name].append(row)
        print(name, i, json.dumps(row), file=sys.stderr)
    result["median_us_per_tick"] = {
        name: {k: statistics.median(r["us_per_tick"].get(k, 0.0) for r in result[name])
               for k in result[name][0]["us_per_tick"]} for name in ("runtime", "floor")}
    write_json(a.out, result)
    print(json.dumps(result["median_us_per_tick"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
