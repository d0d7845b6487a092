"""``fxswarm logger CONFIG --swarm NAME --out DIR --rerun file,grpc,...``: the swarm to Rerun, over Zenoh.

One more process on the bus. It subscribes to ``world/state`` alone (one
message per tick: the world's truth, with the link health the robots
measured at their inboxes) with its *own* Zenoh callback, which only drops
the raw payload and its arrival time into a bounded ring
(:class:`~fxswarm.logger.inbox.Inbox`): the bus never waits on the logger,
and when the logger falls behind it loses the oldest messages and counts
them. The main thread reads the header of each state (:mod:`.peek`); the
log rate skips most of them there, and only the states it draws are
decoded and validated in full (as the Zenoh bus does) and handed to the
:class:`~fxswarm.logger.recorder.SwarmRecorder`.

It says it is alive (``alive/logger/0``) only once it is subscribed and the
recording is open, so a launcher that waits for it loses no tick. It ends
when the world ends the run (after draining what arrived), on SIGINT/SIGTERM,
or when a world gone without ending it has not come back within
``--world-timeout`` s, and always closes the recording so the ``.rrd`` is complete.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import uuid
from pathlib import Path

from fxswarm.core import bus as topics
from fxswarm.core.messages import WireError, decode
from fxswarm.logger.inbox import Inbox
from fxswarm.logger.peek import Header, peek_header
from fxswarm.logger.recorder import RECORDER_TOPICS, RecorderOptions, SwarmRecorder
from fxswarm.logger.sinks import OutputError, open_recording, parse_outputs
from fxswarm.runtime.numbers import positive, positive_int
from fxswarm.runtime.process import RoleProcess, add_process_arguments
from fxswarm.runtime.config import load_or_exit
from fxswarm.runtime.zenoh_bus import check_sender

DRAIN_BATCH = 2000  # messages handled between two looks at liveliness and signals
SETTLE_S = 0.3  # after the world leaves: wait this long for samples still in flight


def _belongs(topic: str, h: Header) -> bool:
    """The header is the kind and role its key promises (as ``zenoh_bus.check_sender``)."""
    return topic == topics.WORLD_STATE and h.kind == "state" and h.role == "world"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_process_arguments(p)  # the options every role process takes (the launcher passes them alike)
    g = p.add_argument_group("logging")
    g.add_argument("--rerun", default="file", metavar="OUTPUTS",
                   help="comma-separated outputs: file[=PATH] (default OUT/recording.rrd), grpc[=URL] "
                        "(a running viewer), spawn (a local viewer), web[=PORT] (serve the web viewer)")
    g.add_argument("--rate", type=positive, default=None, metavar="HZ",
                   help="frames per second of simulation time (default: [logging] rate_hz, else 25)")
    g.add_argument("--velocities", action="store_true", default=None, help="draw velocity arrows")
    g.add_argument("--inbox", type=positive_int, default=4096, metavar="N",
                   help="ring buffer size, messages; beyond it the oldest are dropped and counted")
    g.add_argument("--recording-id", default=None, help="Rerun recording id (default: one per run)")
    g.add_argument("--nice", type=int, default=10, metavar="N",
                   help="lower the logger's CPU priority by N (default 10; 0: unchanged), so on a busy "
                        "machine the swarm's processes run first and the logger catches up in their gaps")


class LoggerProcess:
    """The logger's session, inbox and recorder; :meth:`run` until the world leaves or a signal."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.sc = load_or_exit(args.config)
        self.args = args
        out = Path(args.out or f"runs/{self.sc.name}")
        try:
            self.outputs = parse_outputs(args.rerun, out)
            self.options = RecorderOptions.from_scenario(self.sc, rate_hz=args.rate, velocities=args.velocities)
            self.inbox = Inbox(args.inbox)
        except (OutputError, ValueError) as exc:
            print(f"fxswarm logger: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        # Before the session and the recording start their threads: Linux priorities are per
        # thread, and new threads inherit their creator's.
        self.nice = os.nice(max(0, args.nice)) if args.nice else os.nice(0)
        self.proc = RoleProcess("logger", 0, self.sc, args)
        self.invalid = 0
        self._subscribers = []  # kept referenced: a dropped subscriber stops delivering
        self._cpu_at_start = time.process_time()
        self._thread_at_start = time.thread_time()
        recording_id = args.recording_id or f"{self.sc.name}-{self.proc.bus.swarm}-{uuid.uuid4().hex[:8]}"
        self.rec, said = open_recording(self.outputs, recording_id)
        for line in said:
            print(f"fxswarm logger: {line}", file=sys.stderr)
        self.recorder = SwarmRecorder(self.sc, self.rec, self.options, wall_clock=time.monotonic)
        self.recorder.start()

    def subscribe(self) -> None:
        bus = self.proc.bus
        put = self.inbox.put
        now = time.monotonic

        def on_sample(sample) -> None:  # Zenoh's thread: record the arrival, enqueue, return
            put((sample.payload.to_bytes(), now()))

        (topic,) = RECORDER_TOPICS  # one exact key: every sample is a world state (checked on decode)
        self._subscribers.append(bus.session.declare_subscriber(f"{bus.root}/{topic}", on_sample))
        self.proc.watch(["world/0"])
        self._cpu_at_start = time.process_time()  # start-up (imports, session) is not logging
        self._thread_at_start = time.thread_time()  # decoding and recording; the rest is Zenoh's threads
        bus.declare_alive("logger", 0)

    def drain(self, limit: int | None = DRAIN_BATCH) -> int:
        """Handle queued world states in arrival order: the header of each, the whole of those drawn."""
        n = 0
        recorder = self.recorder
        topic = topics.WORLD_STATE
        for payload, wall in self.inbox.drain(limit):
            n += 1
            h = peek_header(payload)
            if h is None or not _belongs(topic, h):
                self.invalid += 1
            elif not recorder.due(h.t):
                recorder.skipped += 1
            else:
                try:
                    msg = decode(payload)
                    check_sender(topic, msg)
                except WireError:
                    self.invalid += 1
                    continue
                recorder.take(topic, msg, wall)
        recorder.dropped = self.inbox.dropped
        counters = self.proc.bus.counters  # the same counters every process reports in summary.json
        counters.received += n
        counters.invalid = self.invalid
        counters.dropped = self.inbox.dropped
        return n

    def run(self) -> None:
        proc = self.proc
        while not proc.stopping:
            proc.bus.poll(0.02 if len(self.inbox) == 0 else 0)  # liveliness, signals
            if self.drain() == 0:
                self.recorder.flush_if_due()
            proc.check_parent()
            proc.exit_with_world()
        self._settle()

    def _settle(self) -> None:
        """Take what is still queued or in flight, briefly, then stop."""
        quiet_since = time.monotonic()
        end = quiet_since + 2.0
        while time.monotonic() < end:
            if self.drain(None):
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since > SETTLE_S or self.proc.stop_reason.startswith("SIG"):
                return
            time.sleep(0.01)

    def close(self) -> None:
        try:
            self.recorder.close(timeout_s=10.0)
        finally:
            extra = {"logger": {**self.recorder.counters(), "inbox_dropped": self.inbox.dropped,
                                "invalid": self.invalid, "outputs": self.args.rerun, "nice": self.nice,
                                "cpu_s": round(time.process_time(), 3),  # what logging cost this machine
                                "cpu_s_running": round(time.process_time() - self._cpu_at_start, 3),
                                "cpu_s_main_thread": round(time.thread_time() - self._thread_at_start, 3)}}
            self.proc.finish(extra)


def main(args: argparse.Namespace) -> int:
    logger = LoggerProcess(args)
    try:
        logger.subscribe()
        logger.run()
    finally:
        logger.close()
    c = logger.recorder.counters()
    print(f"fxswarm logger: {c['frames']} frames logged, {logger.inbox.dropped} messages dropped "
          f"({logger.proc.stop_reason or 'done'})", file=sys.stderr)
    return logger.proc.exit_status
