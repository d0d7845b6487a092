"""``--rerun web``: two runs on one host never collide on the viewer's ports (issue 18 item 3)."""

from __future__ import annotations

import socket

import pytest

from fxswarm.logger.sinks import OutputError, parse_outputs, port_problem


def test_plain_web_picks_free_ports_each_time(tmp_path):
    a, b = parse_outputs("web", tmp_path), parse_outputs("file,web", tmp_path)
    ports = {a.web_port, a.web_viewer_port, b.web_port, b.web_viewer_port}
    assert len(ports) == 4, ports  # the fixed 9876/9877 of old: the second logger died
    assert all(port_problem(p) is None for p in ports)


def test_a_named_port_in_use_is_refused_before_the_run_naming_it(tmp_path):
    with socket.socket() as taken:
        taken.bind(("", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(OutputError, match=rf"port {port} is in use"):
            parse_outputs(f"web={port}", tmp_path)
        with pytest.raises(OutputError, match=rf"port {port} is in use"):  # PORT+1 is the viewer's
            parse_outputs(f"web={port - 1}", tmp_path)
    free = parse_outputs(f"web={port}", tmp_path)  # once released, the same spec is taken
    assert (free.web_port, free.web_viewer_port) == (port, port + 1)
