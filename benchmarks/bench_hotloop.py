"""The Python work of one lock-step tick, timed in a hot loop: what a process does per tick
without Zenoh, threads or cold caches.

    python benchmarks/bench_hotloop.py [CONFIG] [--robot 1] [--repeat 5] [--out benchmarks/results/hotloop.json]

Runs CONFIG in the in-process simulator once to record, as wire bytes, every
message robot ``--robot`` and the world receive. Then, per tick, it times
(``time.process_time``, one thread) what their processes do with them: decode
and check each message (``decode``, ``check_sender``), hand it to the node,
encode what the node returns. The world's node also builds and encodes the
sensing and state messages. Median over ``--repeat`` passes, us per tick.
Compare with ``bench_threads.py``'s Python-thread CPU per tick of the same
roles: the difference is what landing on a sleeping thread costs.
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

from bench_io import machine, write_json  # noqa: E402  (a sibling script)


def main() -> int:
    from fxswarm.agents.node import AgentNode
    from fxswarm.core.messages import decode, encode
    from fxswarm.core.scenario import load
    from fxswarm.launch.sim import Simulation
    from fxswarm.runtime.zenoh_bus import check_sender
    from fxswarm.world.node import WorldNode

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("config", nargs="?", default=str(ROOT / "configs" / "paper-fast.toml"))
    p.add_argument("--robot", type=int, default=1)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "hotloop.json"))
    a = p.parse_args()
    sc = load(a.config)
    sim = Simulation(sc)
    wanted = {"agent": set(AgentNode(sc, a.robot).subscriptions()), "world": set(WorldNode(sc).subscriptions())}
    heard: dict[str, list[tuple[str, bytes]]] = {"agent": [], "world": []}
    publish_all = sim.bus.publish_all

    def record(out):
        for topic, msg in out:
            for role, topics in wanted.items():
                if topic in topics:
                    heard[role].append((topic, encode(msg)))
        publish_all(out)

    sim.bus.publish_all = record
    sim.run()

    def one_pass(role: str) -> float:
        node = AgentNode(sc, a.robot) if role == "agent" else WorldNode(sc)
        start = time.process_time()
        if role == "world":
            for _, m in node.start():
                encode(m)
        for topic, payload in heard[role]:
            msg = decode(payload)
            check_sender(topic, msg)
            for _, m in node.handle(topic, msg):
                encode(m)
        return 1e6 * (time.process_time() - start) / sc.ticks

    result = {"machine": machine(), "config": a.config, "robot": a.robot, "ticks": sc.ticks,
              "messages_per_tick": {r: round(len(h) / sc.ticks, 3) for r, h in heard.items()}}
    for role in ("agent", "world"):
        runs = [one_pass(role) for _ in range(a.repeat)]
        result[f"{role}_us_per_tick"] = {"median": round(statistics.median(runs), 1), "runs": [round(x, 1) for x in runs]}
    write_json(a.out, result)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
