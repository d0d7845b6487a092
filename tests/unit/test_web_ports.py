"""``--rerun web``: two runs on one host never collide on the viewer's ports (issue 18 item 3)."""

from __future__ import annotations

import socket
from contextlib import ExitStack

import pytest

from fxswarm.logger.sinks import OutputError, parse_outputs, port_problem


def test_plain_web_picks_free_ports_each_time(tmp_path):
    a, b = parse_outputs("web", tmp_path), parse_outputs("file,web", tmp_path)
    ports = {a.web_port, a.web_viewer_port, b.web_port, b.web_viewer_port}
    assert len(ports) == 4, ports  # the fixed 9876/9877 of old: the second logger died
    assert all(port_problem(p) is None for p in ports)


def _listen(port: int) -> socket.socket:
    s = socket.socket()
    try:
        s.bind(("", port))
    except OSError:
        s.close()
        raise
    s.listen()
    return s


def _two_consecutive_ports(stack: ExitStack) -> tuple[socket.socket, socket.socket]:
    """Listen on P and P+1, so no other process on the host can take either while the test runs."""
    for _ in range(50):
        low = stack.enter_context(_listen(0))
        try:
            return low, stack.enter_context(_listen(low.getsockname()[1] + 1))
        except OSError:
            continue
    raise RuntimeError("found no two consecutive free ports in 50 tries")


def test_a_named_port_in_use_is_refused_before_the_run_naming_it(tmp_path):
    with ExitStack() as stack:
        low, taken = _two_consecutive_ports(stack)
        port = taken.getsockname()[1]
        low.close()  # P-1 is free (we held it), P is in use
        with pytest.raises(OutputError, match=rf"port {port} is in use"):
            parse_outputs(f"web={port}", tmp_path)
        with pytest.raises(OutputError, match=rf"port {port} is in use"):  # PORT+1 is the viewer's
            parse_outputs(f"web={port - 1}", tmp_path)
        taken.close()
        free = parse_outputs(f"web={port - 1}", tmp_path)  # once released, the same spec is taken
        assert (free.web_port, free.web_viewer_port) == (port - 1, port)
