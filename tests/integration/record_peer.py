"""A process that serves or fetches a run's record (``world/record``) as one certificate's holder.

``python record_peer.py --connect EP --swarm S [--keys KEYS --as NAME] serve --ticks N``: serve a
record of N ticks signed ``{"who": NAME}`` in its summary, print ``serving``, until stdin closes.
``... fetch --timeout S``: fetch the record, print one JSON line ``{"ok", "who", "ticks", "error"}``.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time

import numpy as np
import zenoh

from fxswarm.core.bus import WORLD_RECORD, prefix
from fxswarm.runtime.record import Record, RecordError, RecordServer, fetch_record
from fxswarm.runtime.tls import files_for


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    p.add_argument("--swarm", required=True)
    p.add_argument("--keys", default=None)
    p.add_argument("--as", dest="name", default="world")
    sub = p.add_subparsers(dest="what", required=True)
    serve = sub.add_parser("serve")
    serve.add_argument("--ticks", type=int, default=10)
    fetch = sub.add_parser("fetch")
    fetch.add_argument("--timeout", type=float, default=5.0)
    a = p.parse_args()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if a.keys:
        files_for(a.keys, a.name).insert_into(conf)
    session = zenoh.open(conf)
    key = f"{prefix(a.swarm)}/{WORLD_RECORD}"
    try:
        if a.what == "serve":
            buf = io.BytesIO()
            np.savez(buf, t=np.arange(a.ticks) * 0.01)
            server = RecordServer(session, key, Record({"ticks": a.ticks, "who": a.name}, buf.getvalue()), chunk_bytes=256)
            print("serving", flush=True)
            sys.stdin.read()  # until the test closes our stdin
            server.close()
            return 0
        end = time.monotonic() + a.timeout
        try:
            record = fetch_record(session, key, lambda: "timeout" if time.monotonic() > end else None, time.sleep,
                                  timeout=1.0)
            out = {"ok": True, "who": record.summary.get("who"), "ticks": record.summary["ticks"], "error": None}
        except RecordError as exc:
            out = {"ok": False, "who": None, "ticks": None, "error": str(exc)}
        print(json.dumps(out), flush=True)
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
