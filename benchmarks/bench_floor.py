"""The floor: fxswarm's message pattern over Zenoh from Python, with nothing else in it.

    python benchmarks/bench_floor.py [CONFIG] [--ticks 2000] [--realtime-s S] [--repeat N]
        [--topology auto|mesh|routed] [--robots-per-process K[,K...]] [--out benchmarks/results/floor.json]

A world process, a leader process and one process per robot exchange the
runtime's messages as the runtime sent them before its crossings were cut
(docs/design.md "Crossings per tick"): the same payload sizes (those of the
runtime's own encoded messages for CONFIG), the same Zenoh options
(publisher flags, router, mesh or routed, ``ZENOH_RUNTIME``) and the same
graph: per tick the world sends a clock (to the leader), one sensing per
robot and the world state (to nobody without a logger); the leader answers
the clock with the leader state for the next tick (to pinned robots); a
robot answers its sensing with its command (to the world) once it holds
its neighbours' (and leader's) messages for that tick, then sends its
estimate for the next tick on a key of its own (pipelined). That is
5N + 2E + P + 4 crossings per tick (paper-fast: 48) against the runtime's
4N + 2E + P + 3 (41): a runtime/floor ratio above 1 is what the fewer
crossings buy. No control
law, no validation, no numpy: Zenoh callbacks put ``(kind, sender,
payload)`` on a queue and the main thread reads the tick (8 bytes) out of
each payload. What the runtime costs above this is the runtime's.

Lock-step (``--ticks``): ticks per second, counted by the world from the end
of tick 0: every process is up by then, but in a mesh a message put before
the link to its receiver has formed is lost, and a floor process starts
fast enough to lose one now and then (tick 0 then closes on its 1 s
timeout, counted in ``missed_ticks``). Real time (``--realtime-s``, ``--rate``): the world ticks at
the rate, robots answer each sensing at once; latency from each sensing put
to its command's arrival, p50/p99, and late ticks. Both count message
crossings per tick (every put and every delivery, all processes).

Other benchmarks import :func:`floor_lockstep` / :func:`floor_realtime` to
measure the floor in the same run as the runtime (interleaved).

``--robots-per-process K``: each agent process hosts K robots (consecutive
ids), each still on its own keys, subscriptions and liveliness token, so the
wire carries what it carries with one process per robot. fxswarm runs one
process per robot; this measures what hosting would change (several K are
run in turn, every repeat).
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

KINDS = ("clock", "sense", "leader", "estimate", "cmd", "state", "end")


# --- the processes (run as `python bench_floor.py --role ...`; imports zenoh only) --------------


def _role_main(argv: list[str]) -> int:
    import zenoh

    p = argparse.ArgumentParser()
    p.add_argument("--role", choices=("world", "leader", "agent"), required=True)
    p.add_argument("--swarm", required=True)
    p.add_argument("--zenoh", required=True, help="json5 config inserts: [[key, value], ...]")
    p.add_argument("--id", default="0", help="robot id; an agent process may host several: 1,2,3")
    p.add_argument("--robots", type=int, required=True)
    p.add_argument("--ticks", type=int, required=True)
    p.add_argument("--neighbours", default="", help="per hosted robot, its neighbours: 2,6;1,3;...")
    p.add_argument("--pinned", default="", help="comma-separated ids of the robots that hear the leader")
    p.add_argument("--sizes", required=True, help="json: payload bytes per kind (cmd per robot id)")
    p.add_argument("--period", type=float, default=0.0, help="world: real time, s between ticks (0: lock-step)")
    p.add_argument("--express", action="store_true")
    p.add_argument("--direct", action="store_true",
                   help="callbacks on Zenoh's receiving thread, not a Python thread per subscriber")
    a = p.parse_args(argv)
    conf = zenoh.Config()
    for key, value in json.loads(a.zenoh):
        conf.insert_json5(key, value)
    session = zenoh.open(conf)
    root = f"fxswarm/{a.swarm}"
    sizes = json.loads(a.sizes)
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    counts = {"sent": 0, "received": 0}
    congestion = zenoh.CongestionControl.DROP if a.period > 0 else zenoh.CongestionControl.BLOCK
    pinned = {int(x) for x in a.pinned.split(",") if x}

    def publisher(key: str, size: int):
        pub = session.declare_publisher(f"{root}/{key}", congestion_control=congestion,
                                        priority=zenoh.Priority.REAL_TIME, express=a.express)
        pad = bytes(max(size - 8, 0))

        def put(tick: int) -> None:
            pub.put(tick.to_bytes(8, "little", signed=True) + pad)
            counts["sent"] += 1

        return put

    subs = []

    def subscribe(key: str, kind: str, sender: int, robot: int = 0) -> None:
        def on_sample(sample, item=(kind, sender, robot)) -> None:
            inbox.put((item, sample.payload.to_bytes()))

        handler = zenoh.handlers.Callback(on_sample, indirect=False) if a.direct else on_sample
        subs.append(session.declare_subscriber(f"{root}/{key}", handler))

    subscribe("floor/end", "end", 0)

    def on_world(sample) -> None:  # the world's session closed: the run is over, whether or not "end" came
        if sample.kind == zenoh.SampleKind.DELETE:
            inbox.put((("end", 0, 0), b""))

    if a.role != "world":
        subs.append(session.liveliness().declare_subscriber(f"{root}/floor/world", on_world))
    cpu0: list[float] = []  # process CPU time (all threads) when the run's traffic began
    out: dict = {"role": a.role, "id": a.id}
    if a.role == "world":
        for i in range(1, a.robots + 1):
            subscribe(f"agent/{i}/cmd", "cmd", i)
        clock = publisher("clock", sizes["clock"])
        senses = [publisher(f"world/sense/{i}", sizes["sense"]) for i in range(1, a.robots + 1)]
        state = publisher("world/state", sizes["state"])
        end = session.declare_publisher(f"{root}/floor/end", congestion_control=zenoh.CongestionControl.BLOCK)
        tokens = [session.liveliness().declare_token(f"{root}/floor/world")]
        up: set[str] = set()
        seen = threading.Event()
        want = a.robots + 1

        def on_token(sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                up.add(str(sample.key_expr))
                if len(up) >= want:
                    seen.set()

        subs.append(session.liveliness().declare_subscriber(f"{root}/alive/**", on_token, history=True))
        if not seen.wait(120):
            print(f"floor world: only {len(up)} of {want} came up", file=sys.stderr)
            return 3
        sent_at: dict[int, float] = {}
        latencies: list[float] = []
        late = 0

        def emit(k: int) -> None:
            clock(k)
            if a.period > 0:
                sent_at[k] = time.monotonic()
            for put in senses:
                put(k)

        start = time.perf_counter()
        cpu0.append(time.process_time())
        counts["sent"] = counts["received"] = 0
        tick, got = 0, 0
        emit(0)
        missed = 0
        if a.period == 0:  # lock-step: the next tick once every command of this one is in
            while tick < a.ticks:
                try:
                    (kind, sender, _), payload = inbox.get(timeout=1.0)
                except queue.Empty:  # as the runtime's --tick-timeout: close the tick, count it
                    (kind, sender, _), payload, got = ("cmd", 0, 0), tick.to_bytes(8, "little", signed=True), a.robots - 1
                    missed += 1
                    counts["received"] -= 1
                counts["received"] += 1
                if int.from_bytes(payload[:8], "little", signed=True) == tick:
                    got += 1
                    if got == a.robots:
                        got = 0
                        tick += 1
                        if tick == 1:  # timed from here: tick 0 may wait on links still forming
                            start = time.perf_counter()
                        if tick < a.ticks:
                            emit(tick)
                        state(tick - 1)
        else:  # real time: ticks at the period, whatever has arrived
            due = time.monotonic() + a.period
            answered: set[tuple[int, int]] = set()
            while tick < a.ticks:
                left = due - time.monotonic()
                try:
                    (kind, sender, _), payload = inbox.get(timeout=left) if left > 0 else inbox.get_nowait()
                except queue.Empty:
                    now = time.monotonic()
                    if now > due + a.period:
                        late += 1
                    due = max(due + a.period, now)
                    state(tick)
                    tick += 1
                    if tick < a.ticks:
                        emit(tick)
                    continue
                counts["received"] += 1
                k = int.from_bytes(payload[:8], "little", signed=True)
                if k in sent_at and (sender, k) not in answered:
                    answered.add((sender, k))
                    latencies.append(time.monotonic() - sent_at[k])
        wall = time.perf_counter() - start
        end.put(b"end")
        timed = a.ticks - 1 if a.period == 0 else a.ticks  # lock-step: ticks after tick 0
        out.update(ticks=a.ticks, wall_s=wall, ticks_per_s=timed / wall, late_ticks=late, missed_ticks=missed,
                   latencies_ms=[round(x * 1e3, 4) for x in latencies])
    elif a.role == "leader":
        subscribe("clock", "clock", 0)
        lead = publisher("leader/state", sizes["leader"])
        sent = -1
        tokens = [session.liveliness().declare_token(f"{root}/alive/leader/0")]
        while True:
            (kind, _, _), payload = inbox.get()
            if kind == "end":
                break
            if not cpu0:
                cpu0.append(time.process_time())
            counts["received"] += 1
            k = int.from_bytes(payload[:8], "little", signed=True)
            if a.period > 0:
                lead(k)
                continue
            for j in range(max(sent + 1, k), min(k + 1, a.ticks - 1) + 1):
                lead(j)
                sent = j
    else:  # one robot, or several hosted by this process (each its own keys, state and token)
        robots = [int(x) for x in a.id.split(",")]
        hosted = {}  # robot id -> its publishers and what it has heard and done
        for me, nb in zip(robots, a.neighbours.split(";")):
            nbrs = [int(x) for x in nb.split(",") if x]
            subscribe(f"world/sense/{me}", "sense", me, me)
            for j in nbrs:
                subscribe(f"agent/{j}/estimate", "estimate", j, me)
            if me in pinned:
                subscribe("leader/state", "leader", 0, me)
            hosted[me] = {"cmd": publisher(f"agent/{me}/cmd", sizes["cmd"][str(me)]),
                         "est": publisher(f"agent/{me}/estimate", sizes["estimate"]),
                         "held": {j: -1 for j in nbrs}, "leader": -1 if me in pinned else 1 << 62,
                         "sense": -1, "acted": -1, "estimated": -1}
        tokens = [session.liveliness().declare_token(f"{root}/alive/agent/{me}") for me in robots]
        while True:
            (kind, sender, me), payload = inbox.get()
            if kind == "end":
                break
            if not cpu0:
                cpu0.append(time.process_time())
            counts["received"] += 1
            k = int.from_bytes(payload[:8], "little", signed=True)
            r = hosted[me]
            if kind == "sense":
                r["sense"] = k
                if a.period > 0:  # real time: act at once on what is held
                    r["cmd"](k)
                    r["est"](k)
                    continue
                if r["estimated"] < k:
                    r["est"](k)
                    r["estimated"] = k
            elif kind == "estimate":
                r["held"][sender] = max(r["held"][sender], k)
            else:
                r["leader"] = max(r["leader"], k)
            sense = r["sense"]
            if (a.period == 0 and sense > r["acted"] and r["leader"] >= sense
                    and all(h >= sense for h in r["held"].values())):
                r["cmd"](sense)
                r["acted"] = sense
                if sense + 1 < a.ticks:
                    r["est"](sense + 1)
                    r["estimated"] = sense + 1
    out.update(counts)
    out["cpu_s"] = time.process_time() - cpu0[0] if cpu0 else 0.0
    print(json.dumps(out), flush=True)
    del subs
    session.close()
    return 0


# --- the launcher ------------------------------------------------------------------------------


def runtime_sizes(sc) -> dict:
    """Payload bytes of the runtime's encoded messages for scenario ``sc`` (typical values)."""
    import numpy as np

    from fxswarm.core.messages import Clock, Command, Estimate, LeaderState, Sense, WorldState, encode

    v = np.array([0.123456789, -1.23456789, 12.3456789])
    n = sc.n
    links = sum(len(sc.neighbours(r.id)) + sc.is_pinned(r.id) for r in sc.robots)
    cmd = {}
    for r in sc.robots:
        m = len(sc.neighbours(r.id)) + sc.is_pinned(r.id)
        cmd[str(r.id)] = len(encode(Command("agent", r.id, 1234, 1234, 12.34, r.id, v, v, False, 0,
                                            (0,) * m, (0,) * m)))
    return {
        "clock": len(encode(Clock("world", 0, 1234, 1234, 12.34))),
        "sense": len(encode(Sense("world", 0, 1234, 1234, 12.34, n, v, v, v))),
        "leader": len(encode(LeaderState("leader", 0, 1234, 1234, 12.34, v))),
        "estimate": len(encode(Estimate("agent", n, 1234, 1234, 12.34, n, v))),
        "cmd": cmd,
        "state": len(encode(WorldState("world", 0, 1234, 1234, 12.34, np.tile(v, (n, 1)), np.tile(v, (n, 1)),
                                       np.tile(v, (n, 1)), np.full(n, 1.5), np.zeros(n, dtype=bool),
                                       np.tile(v, (len(sc.obstacles), 1)), np.zeros(links, dtype=np.int64),
                                       np.zeros(links, dtype=np.int64)))),
    }


def _zenoh_inserts(options) -> list[list[str]]:
    out = [["mode", f'"{options.mode}"'], ["scouting/multicast/enabled", "false"]]
    if options.connect:  # the router may still be starting: keep trying, as the runtime's processes do
        out += [["connect/endpoints", json.dumps(list(options.connect))], ["connect/timeout_ms", "60000"]]
    if options.listen:
        out.append(["listen/endpoints", json.dumps(list(options.listen))])
    return out


def run_floor(config: str | Path, ticks: int, period: float = 0.0, topology: str = "auto",
              direct: bool = False, robots_per_process: int = 1) -> dict:
    """One floor run of scenario ``config``: ``ticks`` lock-step ticks (``period`` 0) or ticks
    paced ``period`` s apart. Returns the world's figures and the crossings per tick.
    ``robots_per_process`` > 1: agent processes host that many robots each (consecutive ids,
    each robot still on its own keys), a design fxswarm does not have, measured for comparison."""
    from fxswarm.core.scenario import load as load_scenario
    from bench_io import start_router  # a sibling script (here, not at the top: role processes import zenoh only)
    from fxswarm.launch.launcher import ZENOH_RUNTIME, auto_topology, free_port, topology_options

    sc = load_scenario(str(config))
    if topology == "auto":
        topology = auto_topology(sc)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    options = topology_options(topology, endpoint)
    swarm = f"floor-{os.getpid()}-{time.monotonic_ns()}"
    env = {"ZENOH_RUNTIME": ZENOH_RUNTIME, **os.environ}
    pinned = ",".join(str(r.id) for r in sc.robots if sc.is_pinned(r.id))
    common = ["--swarm", swarm, "--zenoh", json.dumps(_zenoh_inserts(options)), "--robots", str(sc.n),
              "--ticks", str(ticks), "--sizes", json.dumps(runtime_sizes(sc)), "--pinned", pinned,
              "--period", repr(period)]
    if direct:
        common.append("--direct")
    if period > 0:
        common.append("--express")  # the runtime keeps express in real time, batches in lock-step
    me = [sys.executable, str(Path(__file__).resolve())]
    router = start_router(endpoint, "--swarm", swarm, env=env)
    procs: list[subprocess.Popen] = []
    try:
        argv = [me + ["--role", "leader", *common]]
        ids = [r.id for r in sc.robots]
        for group in (ids[k:k + robots_per_process] for k in range(0, len(ids), robots_per_process)):
            argv.append(me + ["--role", "agent", "--id", ",".join(map(str, group)), "--neighbours",
                              ";".join(",".join(str(j) for j in sc.neighbours(i)) for i in group), *common])
        argv.append(me + ["--role", "world", *common])
        for cmd in argv:
            procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env))
        outs = []
        limit = time.monotonic() + 120 + ticks * max(period, 0.05)
        for pr in procs:
            so, se = pr.communicate(timeout=max(1.0, limit - time.monotonic()))
            if pr.returncode != 0 or not so.strip():
                raise RuntimeError(f"floor process {pr.args[3:7]} failed ({pr.returncode}): {se[-2000:]}")
            outs.append(json.loads(so.strip().splitlines()[-1]))
    finally:
        for pr in procs:
            if pr.poll() is None:
                pr.kill()
                pr.wait()
        router.terminate()
        router.wait(timeout=10)
    world = outs[-1]
    crossings = sum(o["sent"] + o["received"] for o in outs)
    res = {"agents": sc.n, "robots_per_process": robots_per_process, "topology": topology, "ticks": world["ticks"],
           "wall_s": world["wall_s"], "ticks_per_s": world["ticks_per_s"], "crossings_per_tick": round(crossings / world["ticks"], 2),
           "missed_ticks": world["missed_ticks"], "cpu_ms_per_tick": round(1e3 * sum(o["cpu_s"] for o in outs) / world["ticks"], 3),
           "load_avg": os.getloadavg()[0]}
    if period > 0:
        lat = sorted(world["latencies_ms"])
        res.update(rate_hz=1 / period, late_ticks=world["late_ticks"],
                   late_fraction=world["late_ticks"] / world["ticks"],
                   achieved_speed=world["ticks"] * period / world["wall_s"],
                   sense_to_command=_stats(lat))
    return res


def _stats(ms: list[float]) -> dict:
    if not ms:
        return {"n": 0}
    a = sorted(ms)

    def pct(q: float) -> float:
        return a[min(len(a) - 1, int(round(q / 100 * (len(a) - 1))))]

    return {"n": len(a), "p50_ms": pct(50), "p99_ms": pct(99), "max_ms": a[-1], "mean_ms": statistics.fmean(a)}


def floor_lockstep(config: str | Path, ticks: int, topology: str = "auto", robots_per_process: int = 1) -> dict:
    return run_floor(config, ticks, 0.0, topology, robots_per_process=robots_per_process)


def floor_realtime(config: str | Path, duration: float, topology: str = "auto", robots_per_process: int = 1) -> dict:
    from fxswarm.core.scenario import load as load_scenario

    dt = load_scenario(str(config)).dt
    return run_floor(config, int(round(duration / dt)), dt, topology, robots_per_process=robots_per_process)


def main() -> int:
    if "--role" in sys.argv:
        return _role_main(sys.argv[1:])
    sys.path.insert(0, str(ROOT))
    from bench_io import machine, write_json  # a sibling script

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("config", nargs="?", default=str(ROOT / "configs" / "paper-fast.toml"))
    p.add_argument("--ticks", type=int, default=2000, help="lock-step ticks per run (0: no lock-step run)")
    p.add_argument("--realtime-s", type=float, default=0.0, help="also a real-time run this long, s")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--topology", choices=("auto", "mesh", "routed"), default="auto")
    p.add_argument("--robots-per-process", default="1", metavar="K[,K...]",
                   help="agent processes host K robots each (not fxswarm's design: one process per robot; "
                        "measured to show what it would change); several: each in turn, every repeat")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "floor.json"))
    a = p.parse_args()
    hosts = [int(k) for k in a.robots_per_process.split(",")]
    result: dict = {"machine": machine(), "config": a.config, "lockstep": [], "realtime": []}
    for _ in range(a.repeat):
        for k in hosts:  # interleaved: each K once per repeat
            if a.ticks > 0:
                result["lockstep"].append(floor_lockstep(a.config, a.ticks, a.topology, k))
                print("lockstep", json.dumps(result["lockstep"][-1]), file=sys.stderr)
            if a.realtime_s > 0:
                result["realtime"].append(floor_realtime(a.config, a.realtime_s, a.topology, k))
                print("realtime", json.dumps(result["realtime"][-1]), file=sys.stderr)
    if result["lockstep"]:
        result["lockstep_ticks_per_s_median"] = statistics.median(r["ticks_per_s"] for r in result["lockstep"])
    write_json(a.out, result)
    print(json.dumps({k: v for k, v in result.items() if k.endswith("median")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
