"""A rogue router, as its own process: ``python rogue_router.py --listen EP --swarm S --tls JSON``.

It listens where a swarm's processes look for a router when theirs is lost (the next endpoint
they list) with a certificate of the swarm's CA that is not the ``router``'s (a stolen robot's
key), and no rules. It counts every sample it hears under the swarm's prefix (but its own), saying
``heard`` on a line of its own at the first, and, four times a second, puts a forged ``Command`` for
robot 1 (what the world would apply). On SIGTERM it prints one JSON line: ``{"heard": n, "forged": m}``.
"""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time

import numpy as np
import zenoh

from fxswarm.core.messages import Command, encode


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--swarm", required=True)
    p.add_argument("--tls", required=True, help="JSON of transport/link/tls")
    args = p.parse_args()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([args.listen]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/link/tls", args.tls)
    heard = [0]
    root = f"fxswarm/{args.swarm}"
    forged: list[float] = []  # when each forgery went out (time.monotonic: one clock for every process here)
    with zenoh.open(conf) as session:
        def on_sample(sample) -> None:  # not its own forgeries, which its session hands back to it
            if not str(sample.key_expr).endswith("/agent/1/cmd"):
                heard[0] += 1
                if heard[0] == 1:  # the event a test waits for
                    print("heard", flush=True)

        session.declare_subscriber(f"{root}/**", on_sample)
        print("rogue up", flush=True)
        while not stop.wait(0.25):
            forged.append(time.monotonic())
            cmd = Command("agent", 1, 10_000 + len(forged), 0, 0.0, 1, np.array([0.0, 0.0, -4.321]), np.zeros(3), False,
                          0, (), (), None, None, None, None, None)
            session.put(f"{root}/agent/1/cmd", encode(cmd))
    print(json.dumps({"heard": heard[0], "forged": len(forged), "forged_at": forged}), flush=True)


if __name__ == "__main__":
    main()
