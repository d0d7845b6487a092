"""What every benchmark script shares: the machine it ran on, and writing its JSON.

The scripts run as ``python benchmarks/NAME.py``, so this sibling imports as ``bench_io``.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path


def machine() -> dict:
    """The figures a result needs beside it on a shared machine: cores, Python, load."""
    return {"cpus": os.cpu_count(), "python": platform.python_version(),
            "load_avg_at_start": round(os.getloadavg()[0], 2)}


def write_json(path: str | Path, data: dict) -> None:
    """Write a benchmark's result (its folder made if missing)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2) + "\n")


def start_router(endpoint: str, *extra: str, env: dict | None = None) -> subprocess.Popen:
    """A Zenoh router (``fxswarm router``) listening on ``endpoint``, output discarded. It leaves
    when this process does (FXSWARM_PARENT_PID), so a benchmark killed mid-run leaves no router."""
    from fxswarm.runtime.process import PARENT_ENV

    return subprocess.Popen([sys.executable, "-m", "fxswarm.cli", "router", "--listen", endpoint, *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**(env if env is not None else os.environ), PARENT_ENV: str(os.getpid())})


# --- A B A B against another checkout -------------------------------------------------------

#: Python run in a tree's own venv (``run_in_tree``) that prints ``{"act_cpu_us": ...}``: the
#: agent's ``act`` alone, thread CPU us an act, the least of 30 batches of 200, averaged over the
#: robots of ``held`` (a Simulation already run, so each agent holds its last tick's inputs).
ACT_CPU = """
acts = []
for agent in held.agents:
    batches = []
    for _ in range(30):
        c0 = time.thread_time()
        for _ in range(200):
            agent.act(0.01)
        batches.append((time.thread_time() - c0) / 200 * 1e6)
    acts.append(min(batches))
"""


def run_in_tree(tree: Path, code: str, *args: str, what: str = "run") -> dict:
    """Run ``code`` with ``tree``'s own venv and working directory; the JSON its last line prints."""
    done = subprocess.run([str(tree / ".venv" / "bin" / "python"), "-c", code, *args], cwd=tree,
                          capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        raise RuntimeError(f"{what} in {tree} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def ratio(this: list[dict], base: list[dict], key: str) -> dict:
    """Median and range of the per-round ratios this / base of ``key``."""
    r = [a[key] / b[key] for a, b in zip(this, base)]
    return {"median": statistics.median(r), "range": [min(r), max(r)]}


def cpu_floor() -> dict:
    """Seconds of a fixed pure-Python float workload (3-vector arithmetic, as the law's): a change
    in the machine's load shows here, not in the trees compared."""
    start = time.perf_counter()
    x, y, z = 0.1, 0.2, 0.3
    for _ in range(400_000):
        x, y, z = y * 0.999 + z * 0.001, z * 0.999 + x * 0.001, x * 0.999 + y * 0.001
        s = x * x + y * y + z * z
        x, y, z = x / s ** 0.5, y / s ** 0.5, z / s ** 0.5
    return {"cpu_floor_s": time.perf_counter() - start}


def finish(path: str | Path, results: dict, shown: dict) -> int:
    """Stamp the load at the end into ``results['machine']``, write ``results`` to ``path``, print
    ``shown``; the script's exit status."""
    results["machine"]["load_avg_at_end"] = round(os.getloadavg()[0], 2)
    write_json(path, results)
    print(json.dumps(shown, indent=2))
    return 0
