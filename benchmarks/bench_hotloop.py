"""The Python work of one lock-step tick, timed in one process, hot and with its caches evicted:
what a process does per tick, without Zenoh or threads.

    python benchmarks/bench_hotloop.py [CONFIG] [--robot 1] [--repeat 5] [--cold-mb 32]
        [--cold-ticks 1000] [--together K,K,...] [--out benchmarks/results/hotloop.json]

Runs CONFIG in the in-process simulator once to record, as wire bytes, every
message robot ``--robot`` and the world receive. Then, per tick, it times
(``time.perf_counter`` around each message, one thread) what their processes do
with them: decode and check each message (``decode``, ``check_sender``), hand it
to the node, encode what the node returns. The world's node also builds and
encodes the sensing and state messages. Median over ``--repeat`` passes, us per
tick.

Each pass is timed twice, alternately: hot (message after message, as a
tight loop keeps the caches) and cold (before each message, one write per
64-byte line of a ``--cold-mb`` buffer evicts the caches, as the other
processes and threads sharing the cores do between a robot's messages; the
writes are not timed). Compare both with ``bench_threads.py``'s and
``bench_perf.py``'s Python CPU per tick of the same roles in a real run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from bench_io import machine, write_json  # noqa: E402  (a sibling script)


def main() -> int:
    from fxswarm.agents.node import AgentNode
    from fxswarm.core import bus as topics
    from fxswarm.core.messages import decode, decode_carried, encode
    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.zenoh_bus import check_sender
    from fxswarm.world.node import WorldNode

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("config", nargs="?", default=str(ROOT / "configs" / "paper-fast.toml"))
    p.add_argument("--robot", type=int, default=1)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--cold-mb", type=int, default=32,
                   help="buffer written between messages in the cold passes, MB (default 32: this "
                        "machine's last-level cache)")
    p.add_argument("--cold-ticks", type=int, default=1000,
                   help="ticks timed in the cold passes (default 1000: each eviction takes ms)")
    p.add_argument("--together", default="", metavar="K,K,...",
                   help="also time robots 1..K with their caches evicted once per round of their "
                        "messages, not once per message: what K robots would cost in one process "
                        "(a design not built; docs/benchmarks.md says why it is measured)")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "hotloop.json"))
    a = p.parse_args()
    sc = load(a.config)
    sim = Simulation(sc)
    robots = [r.id for r in sc.robots]
    wanted = {"world": set(WorldNode(sc).subscriptions())} | {r: set(AgentNode(sc, r).subscriptions()) for r in robots}
    heard: dict = {role: [] for role in wanted}  # "world" or a robot id -> [(topic, payload)]
    publish_all = sim.bus.publish_all

    def record(out):
        for topic, msg in out:
            for role, keys in wanted.items():
                if topic in keys:
                    heard[role].append((topic, encode(msg)))
        publish_all(out)

    sim.bus.publish_all = record
    sim.run()

    # As the processes read: a robot takes only the estimate off its neighbours' commands.
    readers = {"world": {}} | {r: {topics.command_topic(j): decode_carried for j in sc.neighbours(r)} for r in robots}
    heard["agent"], readers["agent"] = heard[a.robot], readers[a.robot]
    evict = np.zeros(a.cold_mb * 2**20 // 8)  # float64: 8 per 64-byte line
    clock = time.perf_counter
    per_tick = {role: round(len(h) / sc.ticks) for role, h in heard.items()}  # messages (the first ticks')

    sent = {"n": 0}  # messages the nodes sent in the timed passes: that they did their work

    def take(role, node, topic: str, payload: bytes) -> float:
        """What ``role``'s process does with one message, in s."""
        start = clock()
        msg = readers[role].get(topic, decode)(payload)
        check_sender(topic, msg)
        out = node.handle(topic, msg)
        for _, m in out:
            encode(m)
        spent = clock() - start
        sent["n"] += len(out)
        return spent

    def one_pass(role: str, cold: bool) -> float:
        node = AgentNode(sc, a.robot) if role == "agent" else WorldNode(sc)
        start = clock()
        if role == "world":
            for _, m in node.start():
                encode(m)
        spent = clock() - start
        ticks = min(a.cold_ticks, sc.ticks) if cold else sc.ticks
        for topic, payload in heard[role][:per_tick[role] * ticks]:
            if cold:
                evict[::8] += 1.0  # one write per cache line
            spent += take(role, node, topic, payload)
        return 1e6 * spent / ticks

    def together_pass(k: int, evict_each: bool) -> float:
        """Robots 1..k, their i-th messages one after the other: us per robot and tick."""
        group = robots[:k]
        nodes = {r: AgentNode(sc, r) for r in group}
        spent = 0.0
        ticks = min(a.cold_ticks, sc.ticks)
        for i in range(max(per_tick[r] for r in group) * ticks):
            if not evict_each:
                evict[::8] += 1.0
            for r in group:
                if i < per_tick[r] * ticks:
                    if evict_each:
                        evict[::8] += 1.0
                    spent += take(r, nodes[r], *heard[r][i])
        return 1e6 * spent / ticks / k

    result = {"machine": machine(), "config": a.config, "robot": a.robot, "ticks": sc.ticks,
              "messages_per_tick": {r: round(len(heard[r]) / sc.ticks, 3) for r in ("agent", "world")},
              "cold_mb": a.cold_mb}
    for role in ("agent", "world"):
        hot, cold = [], []
        for _ in range(a.repeat):  # alternately, so both see the same machine
            sent["n"] = 0
            hot.append(one_pass(role, cold=False))
            result[f"{role}_sent_per_tick"] = round(sent["n"] / sc.ticks, 3)  # the hot pass goes through every tick
            cold.append(one_pass(role, cold=True))
        for name, runs in ((f"{role}_us_per_tick", hot), (f"{role}_cold_us_per_tick", cold)):
            result[name] = {"median": round(statistics.median(runs), 1), "runs": [round(x, 1) for x in runs]}
        result[f"{role}_cold_over_hot"] = round(statistics.median(cold) / statistics.median(hot), 2)
    for k in [int(x) for x in a.together.split(",") if x]:
        apart, together = [], []
        for _ in range(a.repeat):
            apart.append(together_pass(k, evict_each=True))
            together.append(together_pass(k, evict_each=False))
        result.setdefault("together", []).append({
            "robots": k, "apart_cold_us_per_robot_tick": round(statistics.median(apart), 1),
            "together_cold_us_per_robot_tick": round(statistics.median(together), 1),
            "together_over_apart": round(statistics.median(together) / statistics.median(apart), 2)})
    write_json(a.out, result)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
