"""An attacker on a running swarm, as its own process: ``python attacker.py --connect EP --swarm S ...``.

It opens a Zenoh session (a client of the router, or with ``--mode peer`` a mesh peer that
meets the swarm at the router and then links to the other peers directly, with no rules of
its own), with the TLS section ``--tls`` (a stolen robot's key, one of another CA, or none), waits on liveliness for the world,
then for the world's first message (its clock runs), then for ``--seconds`` from there (or until
the world ends the run) puts forged ``Command``s, each
carrying a forged estimate for the victim's neighbours, and forged ``Estimate``s
alone, on ``agent/<victim>/cmd`` at ``--rate`` Hz, time-stamped with the world's
latest time so they look fresh, while it listens on its own sensing (allowed to
robot 2), the victim's and a non-neighbour's commands (both forbidden; not the keys
it puts on itself, which its own session would hand back to it). Prints one JSON line: whether it connected, what it sent and heard.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import numpy as np
import zenoh

from fxswarm.core.messages import Command, Estimate, WireError, decode, encode

FORGED_V = (0.0, 0.0, -4.321)  # m/s: a command no controller of this scenario gives
FORGED_PH = (1234.5, -678.25, 42.0)  # m: an estimate far from any leader


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    p.add_argument("--swarm", required=True)
    p.add_argument("--tls", default=None, help="JSON of transport/link/tls, or none")
    p.add_argument("--mode", choices=("client", "peer"), default="client")
    p.add_argument("--victim", type=int, default=1)
    p.add_argument("--own", type=int, default=2)
    p.add_argument("--links", type=int, default=3, help="the victim's in-degree (link report length)")
    p.add_argument("--forbidden", default="agent/6/cmd",
                   help="another key to listen on, not robot 2's to hear (robot 6 is no neighbour of 2)")
    p.add_argument("--rate", type=float, default=200.0)
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--wait", type=float, default=60.0, help="how long to wait for the world")
    p.add_argument("--ready", default=None, help="a file to write once the world is seen, before the attack")
    a = p.parse_args()
    root = f"fxswarm/{a.swarm}"
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(a.mode))
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    if a.mode == "peer":
        conf.insert_json5("listen/endpoints", json.dumps([f"{'tls' if a.tls else 'tcp'}/127.0.0.1:0"]))
    # As long as it may wait: a refusal takes the other side's handshake, late on a loaded machine.
    conf.insert_json5("connect/timeout_ms", str(int(max(3.0, a.wait) * 1000)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if a.tls:
        conf.insert_json5("transport/link/tls", a.tls)
    report: dict = {"connected": False, "sent": 0, "heard": {}, "world_seen": False}
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        report["error"] = str(exc)
        print(json.dumps(report), flush=True)
        return 0
    report["connected"] = True
    latest = {"tick": 0, "t": 0.0}
    world_up = threading.Event()
    ticking = threading.Event()  # a message of the world heard: its clock runs
    over = threading.Event()
    lock = threading.Lock()

    def on_sample(sample) -> None:
        key = str(sample.key_expr)[len(root) + 1:]
        with lock:
            report["heard"][key] = report["heard"].get(key, 0) + 1
        try:
            msg = decode(sample.payload.to_bytes())
        except WireError:
            return
        if msg.t > latest["t"]:
            latest.update(tick=msg.tick, t=msg.t)
        ticking.set()

    def on_alive(sample) -> None:
        key = str(sample.key_expr)
        if key.endswith("alive/world/0") and sample.kind == zenoh.SampleKind.PUT:
            world_up.set()
        if key.endswith("run/over"):
            over.set()

    subs = [session.declare_subscriber(f"{root}/world/sense/{a.own}", on_sample),
            session.declare_subscriber(f"{root}/world/sense/{a.victim}", on_sample),
            session.declare_subscriber(f"{root}/{a.forbidden}", on_sample)]
    live = [session.liveliness().declare_subscriber(f"{root}/alive/world/0", on_alive, history=True),
            session.liveliness().declare_subscriber(f"{root}/run/over", on_alive, history=True)]
    try:
        report["world_seen"] = world_up.wait(a.wait)
        if report["world_seen"]:
            cmd_pub = session.declare_publisher(f"{root}/agent/{a.victim}/cmd")
            if a.ready:
                with open(a.ready, "w") as f:
                    f.write("seen the world\n")
            # The window starts with the run, not at the world's token: a world held by --wait-for
            # may start seconds later on a loaded machine (at load 31 a 5 s window then overlapped
            # about 2 s of the 8 s run: 44 puts, robot 2's sensing heard 181 times of 800).
            report["world_ticking"] = ticking.wait(a.wait)
            end = time.monotonic() + a.seconds
            seq = 0
            while time.monotonic() < end and not over.is_set():
                seq += 1
                tick, t = latest["tick"] + 1, latest["t"]
                zeros = tuple([0] * a.links)
                cmd_pub.put(encode(Command("agent", a.victim, 10**6 + seq, tick, t, a.victim, np.array(FORGED_V),
                                           np.array(FORGED_PH), False, 0, zeros, zeros, None,
                                           tick + 1, t, np.array(FORGED_PH), None)))
                cmd_pub.put(encode(Estimate("agent", a.victim, 10**6 + seq, tick, t, a.victim, np.array(FORGED_PH))))
                report["sent"] += 2
                over.wait(1.0 / a.rate)
        # Direct links to other peers (a mesh): what it put went to them, not through the router.
        report["direct_peers"] = len(list(session.info.peers_zid()))
    finally:
        for s in subs + live:
            s.undeclare()
        session.close()
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
