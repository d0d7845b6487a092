"""What one Zenoh message costs a Python process, by receive mechanism.

    python benchmarks/studies/bench_transport.py [--quick] [--mech NAME ...] [--out benchmarks/studies/results/transport.json]

Ping-pong between two Python processes (clients of a Python router,
``fxswarm router``): the ping process sends, the pong process answers, the
ping process sends the next one when the answer arrives (no pacing, no
busy-wait). For each receive mechanism it records round trips per second and
the CPU seconds each process (ping, pong, router; all threads, from
``/proc/PID/stat``) spends per round trip. Each round trip is one message
sent and one received by ping and by pong, and two routed by the router.

Like a role process, each side also holds idle subscriptions (three data
keys and a liveliness watch) beside the one that carries the traffic.

Mechanisms (how a received sample reaches the code that answers it):

- ``queue``: zenoh-python's default "indirect" callback (a Python thread per
  subscriber fed from Zenoh's thread) puts the bytes on a ``SimpleQueue``;
  the main thread ``get``s them and answers (the bus before this benchmark);
- ``queue-direct``: the same, with ``Callback(indirect=False)`` (the callback
  runs on Zenoh's own thread);
- ``inline``: the indirect callback thread answers itself, no main-thread hop;
- ``inline-direct``: Zenoh's own thread answers (``indirect=False``);
- ``fifo``: a ``FifoChannel`` per subscriber, the main thread blocks in
  ``recv()`` on the traffic's channel (only possible with one busy key);
- ``bus``: :class:`fxswarm.runtime.zenoh_bus.ZenohBus` with real messages
  (encode, decode, validation included), ``poll(timeout)`` (queue path);
- ``bus-stay``: the same with ``poll(timeout, stay=True)`` (the inline path the
  lock-step loops use).

``--runtime RON`` adds runs with ``ZENOH_RUNTIME`` set in the ping and pong
processes (tokio worker threads per Zenoh runtime, e.g.
``(rx: (worker_threads: 1), tx: (worker_threads: 1))``).
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

# The maintained benchmarks this study imports (bench_io, ...) sit one folder up.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_io import machine, start_router, write_json  # noqa: E402  (sibling scripts)
from bench_runtime import cpu_s  # noqa: E402  (CPU time from /proc)

MECHANISMS = ("queue", "queue-direct", "inline", "inline-direct", "fifo", "bus", "bus-stay")
IDLE_KEYS = ("agent/90/estimate", "agent/91/estimate", "leader/state")
PAYLOAD = b"x" * 100


# --- the two sides (run in their own processes) ----------------------------------------------


def worker(side: str, mech: str, endpoint: str, n: int, warmup: int) -> None:
    """One side of the ping-pong; ping prints ``ready``, waits for a line on stdin, runs ``n``
    round trips and prints their wall time as JSON; pong answers until stdin closes."""
    if mech.startswith("bus"):
        return bus_worker(side, endpoint, n, warmup, stay=mech == "bus-stay")
    import zenoh

    from fxswarm.runtime.zenoh_bus import ZenohOptions

    session = zenoh.open(ZenohOptions("client", (endpoint,), (), False).config())
    try:
        inbound, outbound = ("bench/pong", "bench/ping") if side == "ping" else ("bench/ping", "bench/pong")
        pub = session.declare_publisher(outbound, congestion_control=zenoh.CongestionControl.BLOCK,
                                        priority=zenoh.Priority.REAL_TIME, express=True)
        lock = threading.Lock()
        replies: queue.SimpleQueue = queue.SimpleQueue()
        done = threading.Event()
        left = [warmup]  # ping: round trips still to make in this phase
        started = [0.0]

        def answer(payload: bytes) -> None:
            if side == "pong":
                pub.put(payload)
                return
            left[0] -= 1
            if left[0] > 0:
                pub.put(payload)
            else:
                done.set()

        subs = []
        if mech in ("queue", "queue-direct"):
            indirect = mech == "queue"
            put = replies.put
            handler = zenoh.handlers.Callback(lambda s: put(s.payload.to_bytes()), indirect=indirect)
            subs.append(session.declare_subscriber(inbound, handler))
            for key in IDLE_KEYS:
                subs.append(session.declare_subscriber(
                    key, zenoh.handlers.Callback(lambda s: put(s.payload.to_bytes()), indirect=indirect)))
        elif mech in ("inline", "inline-direct"):
            def on_sample(s) -> None:
                with lock:
                    answer(s.payload.to_bytes())
            indirect = mech == "inline"
            subs.append(session.declare_subscriber(inbound, zenoh.handlers.Callback(on_sample, indirect=indirect)))
            for key in IDLE_KEYS:
                subs.append(session.declare_subscriber(key, zenoh.handlers.Callback(on_sample, indirect=indirect)))
        elif mech == "fifo":
            traffic = session.declare_subscriber(inbound, zenoh.handlers.FifoChannel(256))
            subs = [session.declare_subscriber(key, zenoh.handlers.FifoChannel(256)) for key in IDLE_KEYS]
        else:
            raise SystemExit(f"unknown mechanism {mech!r}")
        # Kept: an undeclared (garbage-collected) token or watch is gone from the network.
        watch = session.liveliness().declare_subscriber("bench/alive/**", lambda s: None, history=True)
        token = session.liveliness().declare_token(f"bench/alive/{side}")

        def main_loop(until) -> None:
            """Receive on the main thread (queue, fifo) until ``until()``."""
            while not until():
                if mech == "fifo":
                    sample = traffic.recv()
                    for idle in subs:  # the other keys, drained after each arrival
                        while idle.try_recv() is not None:
                            pass
                    answer(sample.payload.to_bytes())
                elif mech.startswith("queue"):
                    try:
                        answer(replies.get(timeout=0.1))
                    except queue.Empty:
                        pass
                else:
                    done.wait(0.1)

        if side == "pong":
            stop = threading.Event()

            def on_eof() -> None:
                sys.stdin.read()
                stop.set()
                if mech == "fifo":  # recv() blocks: one more ping to ourselves ends it
                    session.put(inbound, PAYLOAD)
            threading.Thread(target=on_eof, daemon=True).start()
            main_loop(stop.is_set)
            return
        wait_for_pong(session)
        for phase, count in (("warmup", warmup), ("measure", n)):
            done.clear()
            left[0] = count
            if phase == "measure":
                print("ready", flush=True)
                sys.stdin.readline()
            started[0] = time.perf_counter()
            pub.put(PAYLOAD)
            main_loop(done.is_set)
        wall = time.perf_counter() - started[0]
        print(json.dumps({"round_trips": n, "wall_s": wall}), flush=True)
        del watch, token, subs
    finally:
        session.close()


def wait_for_pong(session) -> None:
    up = threading.Event()
    watch = session.liveliness().declare_subscriber("bench/alive/pong", lambda s: up.set(), history=True)
    if not up.wait(30):
        raise SystemExit("pong never came up")
    watch.undeclare()


def bus_worker(side: str, endpoint: str, n: int, warmup: int, stay: bool) -> None:
    """The same ping-pong through :class:`ZenohBus` (real messages, validated)."""
    from fxswarm.core.messages import Clock
    from fxswarm.runtime.zenoh_bus import ZenohBus, ZenohOptions

    bus = ZenohBus("bench", ZenohOptions("client", (endpoint,), (), False))
    try:
        inbound, outbound = ("bench/pong", "clock") if side == "ping" else ("clock", "bench/pong")
        left = [warmup]
        seq = [0]
        alive: set[str] = set()

        def message() -> Clock:
            seq[0] += 1
            return Clock(role="world", sender=0, seq=seq[0], tick=seq[0], t=seq[0] * 0.01)

        def on_message(topic, msg) -> None:
            if side == "pong":
                bus.publish(outbound, message())
                return
            left[0] -= 1
            if left[0] > 0:
                bus.publish(outbound, message())
            else:
                bus.wake()

        bus.subscribe(inbound, on_message)
        for key in IDLE_KEYS:
            bus.subscribe(key, on_message)
        bus.watch_alive("**", lambda name, up: alive.add(name) if up else alive.discard(name))
        bus.declare_alive(side, 0)
        if side == "pong":
            stop = threading.Event()
            threading.Thread(target=lambda: (sys.stdin.read(), stop.set(), bus.wake()), daemon=True).start()
            while not stop.is_set():
                bus.poll(0.1, stay=stay)
            return
        end = time.monotonic() + 30
        while "pong/0" not in alive and time.monotonic() < end:
            bus.poll(0.1)
        for phase, count in (("warmup", warmup), ("measure", n)):
            left[0] = count
            if phase == "measure":
                print("ready", flush=True)
                sys.stdin.readline()
            started = time.perf_counter()
            bus.publish(outbound, message())
            while left[0] > 0:
                bus.poll(0.1, stay=stay)
        wall = time.perf_counter() - started
        print(json.dumps({"round_trips": n, "wall_s": wall}), flush=True)
    finally:
        bus.close()


# --- the driver --------------------------------------------------------------------------------


def measure(mech: str, n: int, warmup: int, runtime: str | None) -> dict:
    from fxswarm.launch.launcher import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ)
    if runtime:
        env["ZENOH_RUNTIME"] = runtime
    router = start_router(endpoint)
    me = [sys.executable, __file__, "--worker"]
    args = [mech, endpoint, str(n), str(warmup)]
    pong = subprocess.Popen(me + ["pong"] + args, stdin=subprocess.PIPE, cwd=ROOT, env=env, text=True)
    ping = subprocess.Popen(me + ["ping"] + args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            cwd=ROOT, env=env, text=True)
    procs = {"ping": ping, "pong": pong, "router": router}
    try:
        line = ping.stdout.readline()
        if line.strip() != "ready":
            raise RuntimeError(f"{mech}: ping said {line!r} instead of 'ready'")
        before = {name: cpu_s(p.pid) for name, p in procs.items()}
        ping.stdin.write("go\n")
        ping.stdin.flush()
        line = ping.stdout.readline()
        after = {name: cpu_s(p.pid) for name, p in procs.items()}
        result = json.loads(line)
    finally:
        for p in (ping, pong):
            if p.stdin and not p.stdin.closed:
                p.stdin.close()
        for p in (ping, pong):
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        router.terminate()
        router.wait(timeout=10)
    trips = result["round_trips"]
    cpu_us = {name: round(1e6 * (after[name] - before[name]) / trips, 1) for name in procs}
    return {"mechanism": mech, "zenoh_runtime": runtime, "round_trips": trips,
            "round_trips_per_s": round(trips / result["wall_s"], 1),
            "cpu_us_per_round_trip": cpu_us, "load_avg": round(os.getloadavg()[0], 2)}


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        side, mech, endpoint, n, warmup = sys.argv[2:7]
        worker(side, mech, endpoint, int(n), int(warmup))
        return 0
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "studies" / "results" / "transport.json"))
    p.add_argument("--quick", action="store_true", help="fewer round trips (a smoke run)")
    p.add_argument("--mech", choices=MECHANISMS, action="append", help="only these mechanisms (repeatable)")
    p.add_argument("--runtime", action="append", default=[], metavar="RON",
                   help="also run with ZENOH_RUNTIME=RON in ping and pong (repeatable)")
    p.add_argument("--repeat", type=int, default=1, help="runs per mechanism, interleaved")
    args = p.parse_args()
    n, warmup = (500, 100) if args.quick else (5000, 500)
    runs = []
    for _ in range(args.repeat):
        for runtime in [None] + args.runtime:
            for mech in args.mech or MECHANISMS:
                r = measure(mech, n, warmup, runtime)
                print(json.dumps(r), file=sys.stderr, flush=True)
                runs.append(r)
    result = {"machine": machine(),
              "payload_bytes": len(PAYLOAD), "idle_subscriptions": len(IDLE_KEYS), "runs": runs}
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
