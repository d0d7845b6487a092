"""A router that declares no token, started as zenohd is: ``python tokenless_router.py -c FILE``.

It opens a Zenoh router session from the configuration file ``fxswarm run`` writes for zenohd
(docs/routers.md) and declares nothing: processes must see its outage by their own link to it.
"""

from __future__ import annotations

import signal
import sys
import threading

import zenoh


def main() -> None:
    if sys.argv[1:2] != ["-c"] or len(sys.argv) != 3:
        raise SystemExit("usage: tokenless_router.py -c FILE")
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    zenoh.init_log_from_env_or("warn")
    session = zenoh.open(zenoh.Config.from_json5(open(sys.argv[2]).read()))
    try:
        stop.wait()
    finally:
        session.close()


if __name__ == "__main__":
    main()
