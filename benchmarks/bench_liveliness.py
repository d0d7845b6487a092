"""How soon a robot that stops is seen gone: killed, leaving cleanly, or frozen (the Zenoh lease).

    .venv/bin/python benchmarks/bench_liveliness.py [--rounds 5] [--lease-ms 10000]
        [--out benchmarks/results/liveliness.json]

The timing tests/docker/test_docker_compose.py used to assert ("a killed robot is seen gone at
once, not when its lease runs out") and now only prints: under a loaded suite the watcher
itself lags seconds, so the test's figure spread over the lease it was to be told from.

A router (``fxswarm router``) and a watcher (a client session in this process, as a swarm
process watches ``alive/agent/*``); per case a fresh subject process, a client of the router
that declares its ``alive/agent/N`` token as a robot does. Time from the signal to the
watcher's callback for the token's deletion:

* ``left_s`` (the floor): SIGTERM, the subject closes its session (a clean exit);
* ``killed_s``: SIGKILL (``docker kill``, a crash): the kernel closes its socket, the router
  drops the token; it should be about the floor;
* ``frozen_s``: SIGSTOP (a hung process, a cut cable): nothing closes, so the token goes
  only when the lease the subject announced runs out at the router (``--lease-ms``; a Zenoh peer
  is timed out by the lease it announced itself, so the router needs no setting). It counts from
  the last keep-alive heard, sent every quarter lease, so this is 0.75-1 lease plus the check.

Rounds interleave the cases (left, killed, frozen, left, ...); medians and every run are written.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench_io import machine, start_router, write_json  # a sibling script

ROOT = Path(__file__).resolve().parents[1]
SWARM = "bench-liveliness"

# The subject: a router client with a robot's token, that closes its session on SIGTERM and
# leaves when this benchmark does (its stdin closes), so a killed benchmark leaves nothing.
SUBJECT = """
import os, signal, sys, threading
from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions
signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM})
endpoint, ident, lease = sys.argv[1], sys.argv[2], int(sys.argv[3])
bus = ZenohBus(%r, ZenohOptions(mode="client", connect=(endpoint,), multicast=False, lease_ms=lease))
bus.declare_alive("agent", ident)
threading.Thread(target=lambda: (sys.stdin.read(), os.kill(os.getpid(), signal.SIGTERM)), daemon=True).start()
print("up", flush=True)
signal.sigwait({signal.SIGTERM})
bus.close()
""" % SWARM

SIGNALS = {"left_s": signal.SIGTERM, "killed_s": signal.SIGKILL, "frozen_s": signal.SIGSTOP}


class Watcher:
    """A client session that stamps, on Zenoh's callback thread, when each robot's token goes."""

    def __init__(self, endpoint: str, lease_ms: int) -> None:
        from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions

        self.bus = ZenohBus(SWARM, ZenohOptions(mode="client", connect=(endpoint,), multicast=False,
                                                lease_ms=lease_ms))
        self.changes: dict[tuple[str, bool], float] = {}
        self.changed = threading.Condition()
        self.bus.session.liveliness().declare_subscriber(f"{self.bus.root}/alive/agent/*", self._on_change)

    def _on_change(self, sample) -> None:
        import zenoh

        now = time.perf_counter()
        with self.changed:
            self.changes[(str(sample.key_expr).rsplit("/", 1)[-1], sample.kind == zenoh.SampleKind.PUT)] = now
            self.changed.notify_all()

    def wait(self, ident: str, up: bool, timeout: float) -> float:
        with self.changed:
            if not self.changed.wait_for(lambda: (ident, up) in self.changes, timeout):
                raise RuntimeError(f"agent {ident}'s token never {'came' if up else 'went'} within {timeout:g} s")
            return self.changes[(ident, up)]


def one_case(endpoint: str, watcher: Watcher, ident: str, sig: signal.Signals, lease_ms: int) -> float:
    subject = subprocess.Popen([sys.executable, "-c", SUBJECT, endpoint, ident, str(lease_ms)], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True)
    try:
        if subject.stdout.readline().strip() != "up":
            raise RuntimeError(f"subject {ident} exited {subject.wait()} before it was up")
        watcher.wait(ident, True, 60)
        t0 = time.perf_counter()
        os.kill(subject.pid, sig)
        return watcher.wait(ident, False, 3 * lease_ms / 1000 + 30) - t0
    finally:
        if subject.poll() is None:
            subject.kill()
            os.kill(subject.pid, signal.SIGCONT)
        subject.wait()


def main() -> int:
    from fxswarm.launch.launcher import free_port

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--lease-ms", type=int, default=10_000, help="every session's lease (Zenoh's default: 10000)")
    p.add_argument("--cases", default=",".join(SIGNALS), help="which cases, comma-separated")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "liveliness.json"))
    args = p.parse_args()
    cases = args.cases.split(",")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = start_router(endpoint, "--swarm", SWARM)
    runs: dict[str, list[float]] = {name: [] for name in cases}
    loads = []
    try:
        watcher = Watcher(endpoint, args.lease_ms)
        n = 0
        for i in range(args.rounds):
            loads.append(round(os.getloadavg()[0], 2))
            for name in cases:
                n += 1
                runs[name].append(one_case(endpoint, watcher, str(n), SIGNALS[name], args.lease_ms))
                print(f"round {i + 1}: {name} {runs[name][-1]:.3f} s", file=sys.stderr)
        watcher.bus.close()
    finally:
        router.terminate()
        router.wait()
    medians = {name: round(statistics.median(v), 4) for name, v in runs.items()}
    result = {"machine": machine(), "load_avg_per_round": loads, "rounds": args.rounds, "lease_ms": args.lease_ms,
              "runs_s": {k: [round(x, 4) for x in v] for k, v in runs.items()}, "median_s": medians}
    if "left_s" in medians and "killed_s" in medians:
        result["killed_over_left"] = round(medians["killed_s"] / medians["left_s"], 2)
    write_json(args.out, result)
    print(json.dumps({"median_s": medians, "lease_ms": args.lease_ms}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
