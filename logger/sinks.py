"""Opening a recording on the outputs named by ``--rerun``, any combination of:

- ``file`` or ``file=PATH``: an ``.rrd`` file (default ``<out>/recording.rrd``);
- ``grpc`` or ``grpc=URL``: stream to a running viewer
  (default ``rerun+http://127.0.0.1:9876/proxy``);
- ``spawn``: start a local viewer and stream to it (needs a display);
- ``web`` or ``web=PORT``: serve the data over gRPC and the web viewer, for a
  browser: plain ``web`` on two free ports (two runs on one host never
  collide), ``web=PORT`` on PORT and PORT+1, refused before the run starts
  when either is taken.
"""

from __future__ import annotations

import errno
import socket
import uuid
from dataclasses import dataclass
from pathlib import Path

import rerun as rr

from fxswarm.logger import style

DEFAULT_GRPC = "rerun+http://127.0.0.1:9876/proxy"
KINDS = ("file", "grpc", "spawn", "web")


class OutputError(ValueError):
    """A ``--rerun`` value that names no known output."""


@dataclass(frozen=True)
class Outputs:
    file: Path | None = None
    grpc: str | None = None
    spawn: bool = False
    web_port: int | None = None  # the gRPC server the web viewer reads from
    web_viewer_port: int | None = None  # the web viewer's own page


def parse_outputs(spec: str, out_dir: str | Path) -> Outputs:
    """Parse ``"file,grpc=URL,web"`` into :class:`Outputs`; raise :class:`OutputError` naming the bad part."""
    file = grpc = web_port = viewer_port = None
    spawn = False
    for part in (p.strip() for p in spec.split(",") if p.strip()):
        kind, _, value = part.partition("=")
        if kind == "file":
            file = Path(value) if value else Path(out_dir) / "recording.rrd"
        elif kind == "grpc":
            grpc = value or DEFAULT_GRPC
        elif kind == "spawn":
            spawn = True
        elif kind == "web":
            try:
                web_port = int(value) if value else None
            except ValueError:
                raise OutputError(f"--rerun {part!r}: expected web or web=PORT") from None
            if web_port is None:
                web_port, viewer_port = free_tcp_port(), free_tcp_port()
            else:
                viewer_port = web_port + 1
                for port in (web_port, viewer_port):
                    problem = port_problem(port)
                    if problem:
                        raise OutputError(f"--rerun {part!r}: port {port} {problem}; name other ports "
                                          f"(web=PORT takes PORT and PORT+1) or write plain `web` for free ones")
        else:
            raise OutputError(f"--rerun {part!r}: expected a comma-separated list of {', '.join(KINDS)}")
    if file is None and grpc is None and not spawn and web_port is None:
        raise OutputError(f"--rerun {spec!r}: names no output")
    return Outputs(file, grpc, spawn, web_port, viewer_port)


def free_tcp_port() -> int:
    """A TCP port free on every interface now (the kernel's choice); a race with another
    process taking it before the viewer does is possible but rare (ephemeral ports rotate)."""
    with socket.socket() as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def port_problem(port: int) -> str | None:
    """Why the viewer could not listen on ``port`` (e.g. "is in use"), or None if it can."""
    if not 0 < port < 65535:
        return "is out of range (1-65534)"
    with socket.socket() as s:
        try:
            s.bind(("", port))
        except OSError as exc:
            return "is in use (another run's viewer?)" if exc.errno == errno.EADDRINUSE else f"cannot be used: {exc}"
    return None


def open_recording(outputs: Outputs, recording_id: str | None = None) -> tuple[rr.RecordingStream, list[str]]:
    """A recording (app id ``fxswarm``) writing to ``outputs``, with the default blueprint.

    Returns the stream and lines telling the user where to look.
    """
    rec = rr.RecordingStream(style.APP_ID, recording_id=recording_id or str(uuid.uuid4()))
    bp = style.blueprint()
    sinks, said = [], []
    if outputs.file is not None:
        outputs.file.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(outputs.file)))
        said.append(f"recording to {outputs.file}")
    if outputs.spawn:
        # A viewer of the pinned version, listening on its default port; then stream to it.
        rr.spawn(connect=False, recording=rec)
        if outputs.grpc != DEFAULT_GRPC:
            sinks.append(rr.GrpcSink(DEFAULT_GRPC))
        said.append("spawned a local viewer")
    if outputs.grpc is not None:
        sinks.append(rr.GrpcSink(outputs.grpc))
        said.append(f"streaming to the viewer at {outputs.grpc}")
    if outputs.web_port is not None:
        sinks.append(rr.GrpcServerSink(port=outputs.web_port))
    rec.set_sinks(*sinks, default_blueprint=bp)
    if outputs.web_port is not None:
        uri = f"rerun+http://127.0.0.1:{outputs.web_port}/proxy"
        viewer = outputs.web_viewer_port or outputs.web_port + 1
        rr.serve_web_viewer(web_port=viewer, open_browser=False, connect_to=uri)
        said.append(f"web viewer at http://127.0.0.1:{viewer}/?url={uri}")
    return rec, said
