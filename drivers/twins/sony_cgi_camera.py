"""A simulated Sony network camera (SNC-RZ25N CGI) on http://127.0.0.1:PORT.

Serves the requests :mod:`fgloc.drivers.sony_cgi` sends, backed by the same
:class:`~fgloc.drivers.twins.visca_camera.ViscaCameraEmulator` as the serial and UDP
twins (so head state, limits, motion time and error replies are shared):

* ``POST /command/ptzf.cgi`` ``AbsolutePanTilt=PPPP,TTTT,S`` / ``AbsoluteZoom=ZZZZ`` -> 204
  (400 for a value the camera rejects);
* ``GET /command/visca-ptzf.cgi?visca=HEX`` and ``/command/visca-inquiry.cgi?visca=HEX`` -> 200,
  body = hex of the first VISCA reply (ACK or error; inquiry data);
* ``GET /command/inquiry.cgi?inq=system`` -> ``ModelName=SNC-RZ25N``;
* ``GET /oneshotimage.jpg`` -> JPEG of the renderer's frame (404 without a renderer).

HTTP Basic auth is enforced when the twin has credentials. Faults: ``drop`` closes
the connection without an answer, ``garble`` corrupts one byte of a VISCA reply,
``error`` answers a VISCA error (tunnels) or HTTP 500 (ptzf.cgi), ``slow`` delays the
answer, ``disconnect`` stops the server (connection refused) and restarts it on the
same port after ``reconnect_after`` seconds.
"""

from __future__ import annotations

import base64
import http.server
import threading
import time
import urllib.parse

from fgloc.drivers.ptz_units import SNC_RZ25N, CameraModel
from fgloc.drivers.twins.faults import FaultConfig, FaultInjector
from fgloc.drivers.twins.visca_camera import Renderer, ViscaCameraEmulator
from fgloc.drivers.visca.codec import cmd_pan_tilt_absolute, cmd_zoom_direct


def _signed16(text: str) -> int:
    v = int(text, 16)
    if not 0 <= v <= 0xFFFF:
        raise ValueError(text)
    return v - 0x10000 if v >= 0x8000 else v


class SonyCgiTwin:
    """Threaded HTTP server emulating the camera's CGI; a context manager."""

    def __init__(self, emulator: ViscaCameraEmulator | None = None, faults: FaultConfig | None = None,
                 model: CameraModel = SNC_RZ25N, time_scale: float = 0.0, renderer: Renderer | None = None,
                 user: str | None = None, password: str | None = None, port: int = 0) -> None:
        self.emulator = emulator or ViscaCameraEmulator(model, time_scale=time_scale, renderer=renderer)
        self.faults = FaultInjector(faults)
        self._auth = None
        if user is not None:
            self._auth = "Basic " + base64.b64encode(f"{user}:{password or ''}".encode()).decode("ascii")
        self.requests: list[str] = []  # request lines without headers (never credentials)
        self._server = self._make_server(port)
        self.port = self._server.server_address[1]
        self._lock = threading.Lock()
        self._stopped = False
        self._serve_thread = self._start(self._server)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def _make_server(self, port: int) -> http.server.ThreadingHTTPServer:
        twin = self

        class Handler(http.server.BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.0"

            def log_message(self, format: str, *args) -> None:  # noqa: A002 - silence stderr
                pass

            def do_GET(self) -> None:  # noqa: N802
                twin._dispatch(self, None)

            def do_POST(self) -> None:  # noqa: N802
                length = int(self.headers.get("Content-Length") or 0)
                twin._dispatch(self, self.rfile.read(length).decode("ascii", "replace"))

        server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
        server.daemon_threads = True
        server.allow_reuse_address = True
        return server

    @staticmethod
    def _start(server) -> threading.Thread:
        thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.02},
                                  name="sony-cgi-twin", daemon=True)
        thread.start()
        return thread

    # -- faults
    def disconnect(self, reconnect_after: float | None = None) -> None:
        """Stop answering (connection refused); restart on the same port after ``reconnect_after`` s."""
        with self._lock:
            server = self._server
        threading.Thread(target=self._down, args=(server, reconnect_after), daemon=True).start()

    def _down(self, server, reconnect_after: float | None) -> None:
        server.shutdown()
        server.server_close()
        if reconnect_after is None or self._stopped:
            return
        time.sleep(reconnect_after)
        with self._lock:
            if self._stopped:
                return
            self._server = self._make_server(self.port)
            self._serve_thread = self._start(self._server)

    # -- requests
    def _dispatch(self, h: http.server.BaseHTTPRequestHandler, body: str | None) -> None:
        parts = urllib.parse.urlsplit(h.path)
        self.requests.append(f"{h.command} {parts.path}")
        if self._auth is not None and h.headers.get("Authorization") != self._auth:
            self._send(h, 401, b"", {"WWW-Authenticate": 'Basic realm="camera"'})
            return
        if self.faults.count_request():
            self._send(h, 503, b"")
            self.disconnect(self.faults.config.reconnect_after)
            return
        params = dict(urllib.parse.parse_qsl(parts.query))
        if body:
            params.update(urllib.parse.parse_qsl(body))
        path = parts.path
        if path == "/oneshotimage.jpg":
            self._snapshot(h)
            return
        if path == "/command/inquiry.cgi":
            self._send(h, 200, f"ModelName={self.emulator.model.name}\r\n".encode())
            return
        if path in ("/command/visca-ptzf.cgi", "/command/visca-inquiry.cgi"):
            self._visca(h, params.get("visca", ""))
            return
        if path == "/command/ptzf.cgi":
            self._ptzf(h, params)
            return
        self._send(h, 404, b"")

    def _fate(self, h, can_garble: bool) -> str:
        fate = self.faults.reply_fate(can_be_slow=True)
        if fate == "slow":
            time.sleep(self.faults.config.slow_seconds)
        if fate == "drop":
            h.close_connection = True  # no status line at all: the client sees a dropped connection
        if fate == "garble" and not can_garble:
            fate = "ok"
        return fate

    def _visca(self, h, hex_text: str) -> None:
        try:
            packet = bytes.fromhex(hex_text)
        except ValueError:
            self._send(h, 400, b"")
            return
        code = self.faults.request_error()
        if code is not None:
            reply = self.emulator.error(0 if code in (2, 3) or packet[1:2] == b"\x09" else 1, code)
        else:
            replies = self.emulator.handle(packet)
            reply = replies[0][1] if replies else b""
        fate = self._fate(h, can_garble=True)
        if fate == "drop":
            return
        if fate == "garble":
            reply = self.faults.garble(reply)
        self._send(h, 200, self.faults.line_noise(reply).hex().upper().encode("ascii"))

    def _ptzf(self, h, params: dict[str, str]) -> None:
        m = self.emulator.model
        try:
            if "AbsolutePanTilt" in params:
                p, t, s = params["AbsolutePanTilt"].split(",")
                speed = int(s)
                if not 1 <= speed <= 24:
                    raise ValueError(s)
                packet = cmd_pan_tilt_absolute(1, _signed16(p), _signed16(t), min(speed, m.max_pan_speed),
                                               min(speed, m.max_tilt_speed), m.pan_nibbles)
            elif "AbsoluteZoom" in params:
                packet = cmd_zoom_direct(1, int(params["AbsoluteZoom"], 16))
            else:
                raise ValueError("no known field")
        except ValueError:
            self._send(h, 400, b"")
            return
        if self.faults.request_error() is not None:
            self._send(h, 500, b"")
            return
        replies = self.emulator.handle(packet)
        fate = self._fate(h, can_garble=False)
        if fate == "drop":
            return
        if not replies or replies[0][1][1] & 0xF0 == 0x60:
            self._send(h, 400, b"")
            return
        self._send(h, 204, b"")

    def _snapshot(self, h) -> None:
        if self.emulator.renderer is None:
            self._send(h, 404, b"")
            return
        import cv2

        ok, jpeg = cv2.imencode(".jpg", self.emulator.frame())
        self._send(h, 200, jpeg.tobytes(), {"Content-Type": "image/jpeg"})

    @staticmethod
    def _send(h, status: int, body: bytes, headers: dict[str, str] | None = None) -> None:
        try:
            h.send_response(status)
            for k, v in (headers or {}).items():
                h.send_header(k, v)
            h.send_header("Content-Length", str(len(body)))
            h.end_headers()
            if body:
                h.wfile.write(body)
        except OSError:
            pass

    def close(self) -> None:
        with self._lock:
            self._stopped = True
            server = self._server
        server.shutdown()
        server.server_close()

    def __enter__(self) -> SonyCgiTwin:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
