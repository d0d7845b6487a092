"""Pictures of the live view without a screen: the Rerun viewer itself, headless, on Mesa's software Vulkan.

The viewer of the pinned rerun-sdk (the binary shipped in the ``rerun_cli``
wheel) runs with ``--headless``; Mesa's lavapipe (Debian packages
``mesa-vulkan-drivers`` and ``libvulkan1``) renders on the CPU when there is
no GPU. The recording is opened, the time cursor set to each chosen
simulation time, and the whole window (the default blueprint) saved as PNG.
About 3-7 s a shot on a 2-core machine.
"""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

#: Where Debian's mesa-vulkan-drivers puts lavapipe's loader manifest.
LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
INSTALL_HINT = "apt-get install -y mesa-vulkan-drivers libvulkan1 (.ci/install-snapshot-deps.sh does it)"


class SnapshotError(RuntimeError):
    """The viewer cannot render here; the message says what is missing."""


def viewer_binary() -> Path:
    """The ``rerun`` viewer binary of the installed rerun-sdk (not whatever is on PATH)."""
    try:
        import rerun_cli
    except ImportError:
        raise SnapshotError("the rerun_cli package (part of rerun-sdk) is not installed") from None
    path = Path(rerun_cli.__file__).with_name("rerun")
    if not path.is_file():
        raise SnapshotError(f"{path}: the viewer binary is missing from the rerun-sdk wheel")
    return path


def vulkan_icd() -> Path | None:
    """The Vulkan driver manifest to use: ``$VK_ICD_FILENAMES`` if set, else lavapipe's if installed."""
    given = os.environ.get("VK_ICD_FILENAMES")
    if given:
        return Path(given.split(os.pathsep)[0])
    return LAVAPIPE_ICD if LAVAPIPE_ICD.is_file() else None


def can_render() -> str | None:
    """None if a headless shot should work here, else why not."""
    try:
        viewer_binary()
    except SnapshotError as exc:
        return str(exc)
    icd = vulkan_icd()
    if icd is None or not icd.is_file():
        return f"no Vulkan driver: install Mesa's software Vulkan: {INSTALL_HINT}"
    if not any(Path(p).exists() for p in ("/usr/lib/x86_64-linux-gnu/libvulkan.so.1", "/usr/lib/libvulkan.so.1",
                                          "/usr/lib/aarch64-linux-gnu/libvulkan.so.1")):
        return f"no Vulkan loader (libvulkan.so.1): {INSTALL_HINT}"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def render(rrd: Path, times: list[float], out_dir: Path, timeline: str = "sim_time") -> list[Path]:
    """Save the viewer's window (1920x1080, the headless viewer's size) at each simulation time in ``times`` (s) to ``out_dir/view_<t>s.png``."""
    why = can_render()
    if why:
        raise SnapshotError(why)
    from rerun.experimental import ViewerClient

    icd = vulkan_icd()
    os.environ["VK_ICD_FILENAMES"] = str(icd)  # inherited by the viewer process
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")  # winit complains without it, even headless
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        client = ViewerClient.spawn(headless=True, port=_free_port(), hide_welcome_screen=True,
                                    executable_path=str(viewer_binary()), memory_limit="1GiB")
    except Exception as exc:  # noqa: BLE001 - the binding raises plain RuntimeErrors
        raise SnapshotError(f"the viewer did not start: {exc}") from None
    shots = []
    try:
        client.open(str(rrd.resolve()))
        _wait_loaded(client, timeout_s=30.0)
        for t in times:
            client.set_time(timeline, duration=float(t), play_state="paused")
            # The viewer fetches chunks when a frame first needs them: render twice before the
            # real shot, or the plots come out empty.
            for _ in range(2):
                client.take_screenshot(max_size=64)
            time.sleep(0.5)
            path = out_dir / f"view_{t:g}s.png"
            client.save_screenshot(str(path.resolve()))
            shots.append(path)
    except SnapshotError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise SnapshotError(f"the viewer failed while rendering: {exc}") from None
    finally:
        client.quit()
    return shots


def _wait_loaded(client, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        state = client.get_state()
        if not state.loading and any(r.timelines for r in state.recordings):
            return
        time.sleep(0.2)
    raise SnapshotError(f"the recording did not load within {timeout_s:g} s")


def snapshots(run: Path, scenario, times: list[float]) -> list[Path]:
    """Shots of ``run/recording.rrd`` (made from the trajectory first if the run has none)."""
    rrd = run / "recording.rrd"
    if not rrd.is_file():
        from fxswarm.logger.replay import record_run

        record_run(run, rrd, scenario=scenario)
    return render(rrd, times, run / "snapshots")
