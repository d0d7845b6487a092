"""DDS for the tests: the loopback-only Cyclone DDS configuration, a domain of the test's own, and
the robots' stand-in process (``tests/integration/ros2_robots.py``) driven by the lines it says."""

from __future__ import annotations

import itertools
import json
import os
import queue
import secrets
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Loopback only, multicast off: a test sends nothing off this machine.
LOOPBACK_XML = REPO / "tests" / "cyclonedds-loopback.xml"
ROBOTS = REPO / "tests" / "integration" / "ros2_robots.py"
_domains = itertools.count()


def dds_environment() -> dict[str, str]:
    """CYCLONEDDS_URI (loopback, no multicast) with a discovery tag of this test's own, and a
    ROS_DOMAIN_ID spread by pid and test (1..232).

    The tag is what keeps parallel test runs apart: Cyclone DDS discovers only participants with
    the same tag. 232 domains are too few for that: two runs' tests met in one domain, and each
    world flew the other's stand-in robots (poses of both, one's at its start position)."""
    domain = 1 + (os.getpid() * 7 + next(_domains)) % 232
    tag = f"<Discovery><Tag>fxswarm-test-{secrets.token_hex(8)}</Tag></Discovery>"
    return {"CYCLONEDDS_URI": f"{LOOPBACK_XML.as_uri()},{tag}", "ROS_DOMAIN_ID": str(domain)}


class Robots:
    """The stand-in robots as a process; :meth:`wait_for` a line it says, :meth:`finish` for its report."""

    def __init__(self, scenario: Path, folder: Path, *extra: str) -> None:
        self.report_path = folder / "robots-report.json"
        self.proc = subprocess.Popen([sys.executable, str(ROBOTS), str(scenario), "--report", str(self.report_path),
                                      *extra], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.said: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.strip())

    def wait_for(self, line: str, timeout: float = 30.0) -> None:
        """Block until the robots say ``line`` (raises, showing what they said, after ``timeout`` s)."""
        while line not in self.said:
            try:
                self.said.append(self.lines.get(timeout=timeout))
            except queue.Empty:
                raise AssertionError(f"the robots did not say {line!r} within {timeout:g} s; said {self.said}")

    def finish(self, timeout: float = 10.0) -> dict:
        """Stop them (SIGTERM) and return their report."""
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout)
        if not self.report_path.exists():
            while not self.lines.empty():
                self.said.append(self.lines.get())
            raise AssertionError(f"the robots exited {code} without a report; said {self.said}")
        return json.loads(self.report_path.read_text())

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@contextmanager
def running(argv: list) -> Iterator[subprocess.Popen]:
    """A command running (stderr piped) for the ``with`` block; killed if still up when it ends."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
