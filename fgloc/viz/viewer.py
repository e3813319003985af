"""The Rerun viewer: its binary, a native window on an .rrd, and a headless render to PNG.

Every viewer this module starts listens on 127.0.0.1 unless the caller asks otherwise.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path


def viewer_binary() -> Path:
    """The real Rerun viewer binary shipped with rerun-sdk (not the Python wrapper, so
    that killing it does not orphan the viewer)."""
    import rerun_cli

    return Path(rerun_cli.__file__).parent / "rerun"


def has_display() -> bool:
    """Whether a native viewer window can be shown (X11/Wayland display, or macOS/Windows)."""
    if os.name != "posix" or Path("/System/Library").exists():
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def view_rrd(path: str | os.PathLike[str], bind: str = "127.0.0.1") -> int:
    """Open an .rrd in the native viewer and wait until it is closed (returns its exit status).

    The viewer's own server listens on ``bind`` (127.0.0.1 unless the user asks
    otherwise) on a free port.
    """
    cmd = [str(viewer_binary()), "--bind", bind, "--port", "auto", str(path)]
    return subprocess.call(cmd)


@dataclass(frozen=True)
class RenderReport:
    """What a headless render saw: the PNG, each view's error reports, the viewer's
    WARN/ERROR log lines (software-rasterizer warnings excluded)."""

    png: Path
    view_reports: dict[str, list[str]]
    problems: list[str]
    listening: list[str]  # addresses the viewer reported listening on


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def render_headless(
    path: str | os.PathLike[str],
    png: str | os.PathLike[str],
    *,
    window_size: str = "1600x900",
    timeline: str | None = "iteration",
    sequence: int | None = None,
    settle_seconds: float = 4.0,
    timeout: float = 120.0,
) -> RenderReport:
    """Render an .rrd with its default blueprint in a headless viewer (software Vulkan,
    Debian: mesa-vulkan-drivers) and save the whole window as a PNG.

    The viewer listens on 127.0.0.1 only, is driven through
    ``rerun.experimental.ViewerClient``, paused at ``sequence`` of ``timeline``
    (default: its last step), and given ``settle_seconds`` for start-up
    notifications to fade. The process is always terminated.
    """
    from rerun.experimental import ViewerClient

    port = _free_loopback_port()
    cmd = [str(viewer_binary()), "--headless", "--renderer", "vulkan", "--bind", "127.0.0.1", "--port", str(port),
           "--window-size", window_size, "--hide-welcome-screen"]
    deadline = time.monotonic() + timeout
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        client = None
        while client is None:
            if proc.poll() is not None:
                raise RuntimeError(f"headless viewer exited with status {proc.returncode} (is Vulkan available?)")
            if time.monotonic() > deadline:
                raise TimeoutError("headless viewer did not start")
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                client.get_state()
            except Exception:  # not listening yet  # noqa: BLE001 - any viewer failure ends the headless render with a report
                client = None
                time.sleep(0.2)
        client.open(str(Path(path).resolve()))
        while True:
            state = client.get_state()
            if not state.loading:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"{path}: viewer did not finish loading")
            time.sleep(0.1)
        if timeline is not None:
            known = {t.name: t for r in state.recordings for t in r.timelines}
            if timeline in known:
                seq = known[timeline].end if sequence is None else sequence
                if seq is not None:
                    client.set_time(timeline, sequence=int(seq), play_state="paused")
        time.sleep(settle_seconds)
        client.take_screenshot(max_size=64)  # a first frame retires expired start-up notifications
        time.sleep(0.5)
        client.save_screenshot(str(Path(png).resolve()))
        views = client.get_state().views  # reports describe the frame just painted
        reports = {f"{v.view_class}:{v.name}": [str(r) for r in v.reports] for v in views}
        logs = client.get_logs()
        problems = [f"{e.level} {e.target}: {e.message}" for e in logs
                    if e.level in ("WARN", "ERROR") and "oftware rasterizer" not in e.message]
        listening = [m.group(1) for e in logs if e.message.startswith("Listening for")
                     for m in [re.search(r" on (\S+:\d+)", e.message)] if m]
        try:
            client.run_command("ui.quit")
            proc.wait(timeout=10)
        except Exception:  # noqa: BLE001 - any viewer failure ends the headless render with a report
            pass
        return RenderReport(Path(png), reports, problems, listening)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
