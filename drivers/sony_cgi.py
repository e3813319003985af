"""Sony network cameras (SNC-RZ25N family) over their HTTP CGI, with urllib only.

Requests (protocols.md 2.1; spellings to be confirmed on the camera):

* move:      ``POST /command/ptzf.cgi`` form ``AbsolutePanTilt=PPPP,TTTT,S`` (4 hex digits,
  16-bit two's complement counts; S = speed 1..24) -> 204 No Content, returned
  **before** the motion ends;
* zoom:      ``POST /command/ptzf.cgi`` form ``AbsoluteZoom=ZZZZ`` (hex);
* inquiries: ``GET /command/visca-inquiry.cgi?visca=81090612FF`` -> body = VISCA reply as
  hex text (``9050 0p0p0p0p 0t0t0t0t FF``), decoded with :mod:`fgloc.drivers.visca.codec`;
* stop/home: VISCA tunnel ``GET /command/visca-ptzf.cgi?visca=8101...FF``;
* snapshot:  ``GET /oneshotimage.jpg``.

Because HTTP returns before the head stops, :meth:`SonyCgiHead.move_to` polls the
position until the read-back equals the target (timeout sized from distance and
speed); :meth:`SonyCgiHead.position` reads until two successive reads agree. The
spec-radian level (units, mounting, limits, confirmed reads, frames) is the shared
:class:`fgloc.drivers.head_adapter.HeadAdapter`; times are seconds.

Credentials: HTTP Basic, sent in a header built here; they never appear in logs,
``repr``, or exception messages (URLs are shown without user info).
"""

from __future__ import annotations

import base64
import http.client
import logging
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass

import numpy as np

from fgloc.core.retry import RetryPolicy
from fgloc.drivers.head_adapter import FrameSourceArg, HeadAdapter
from fgloc.drivers.ptz_units import SNC_RZ25N, PanTiltUnits
from fgloc.drivers.visca.codec import (
    Reply,
    ReplyKind,
    cmd_home,
    cmd_pan_tilt_position_inquiry,
    cmd_pan_tilt_stop,
    cmd_zoom_position_inquiry,
    decode_pan_tilt,
    decode_zoom,
    parse_reply,
)
from fgloc.drivers.visca.errors import ViscaDisconnected, ViscaError, ViscaProtocolError, ViscaTimeout, error_for

log = logging.getLogger(__name__)


class SonyCgiError(ViscaError):
    """The camera's web server refused a request (HTTP status), or authentication failed."""


class SonyCgiServerError(SonyCgiError):
    """HTTP 5xx: the camera's web server failed this time; the request is retried."""


@dataclass(frozen=True)
class Credentials:
    """HTTP Basic credentials; ``repr`` hides the password."""

    user: str
    password: str

    def __repr__(self) -> str:
        return f"Credentials(user={self.user!r}, password=***)"

    def header(self) -> str:
        token = base64.b64encode(f"{self.user}:{self.password}".encode()).decode("ascii")
        return f"Basic {token}"


def split_url(url: str) -> tuple[str, Credentials | None]:
    """``http://user:pw@host[:port]`` -> (``http://host[:port]``, credentials or None)."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise SonyCgiError("--port: expected http://HOST[:PORT]")
    netloc = parts.hostname if ":" not in parts.hostname else f"[{parts.hostname}]"
    try:
        if parts.port:
            netloc += f":{parts.port}"
    except ValueError:
        raise SonyCgiError(f"--port: bad port number in http://{parts.hostname}") from None
    creds = None
    if parts.username is not None:
        creds = Credentials(urllib.parse.unquote(parts.username), urllib.parse.unquote(parts.password or ""))
    return f"{parts.scheme}://{netloc}", creds


def hex16(value: int) -> str:
    """Signed count -> 4 upper-case hex digits of its 16-bit two's complement (``-1000`` -> ``FC18``)."""
    if not -0x8000 <= value <= 0xFFFF:
        raise ValueError(f"{value} does not fit in 16 bits")
    return f"{value & 0xFFFF:04X}"


class SonyCgiClient:
    """Thin HTTP client: one method per request kind, retries on connection trouble."""

    def __init__(self, base_url: str, credentials: Credentials | None = None, timeout: float = 2.0,
                 retries: int = 2) -> None:
        self.base_url, url_creds = split_url(base_url)
        self._credentials = credentials or url_creds
        self.timeout = timeout
        self.retries = retries

    def __repr__(self) -> str:
        return f"SonyCgiClient({self.base_url!r})"

    def request(self, path: str, query: dict[str, str] | None = None, form: dict[str, str] | None = None) -> bytes:
        """GET (or POST when ``form``) ``path``; returns the body. Retries timeouts/resets/5xx
        (``retries`` times, 0.05 s apart); 4xx and authentication failures raise at once."""
        url = self.base_url + path
        if query:
            url += "?" + urllib.parse.urlencode(query, safe=",")
        data = urllib.parse.urlencode(form, safe=",").encode("ascii") if form is not None else None

        def attempt(n: int) -> bytes:
            req = urllib.request.Request(url, data=data, method="POST" if data is not None else "GET")
            if self._credentials is not None:
                req.add_header("Authorization", self._credentials.header())
            try:
                with urllib.request.urlopen(req, timeout=self.timeout) as resp:
                    return resp.read()
            except urllib.error.HTTPError as exc:
                if exc.code in (401, 403):
                    raise SonyCgiError(f"{self.base_url}{path}: HTTP {exc.code}: authentication failed "
                                       "(check the user and password)") from None
                cls = SonyCgiServerError if exc.code >= 500 else SonyCgiError
                raise cls(f"{self.base_url}{path}: HTTP {exc.code} {exc.reason}") from None
            except urllib.error.URLError as exc:
                reason = exc.reason
                if isinstance(reason, ConnectionRefusedError) or "refused" in str(reason).lower():
                    raise ViscaDisconnected(f"{self.base_url}: connection refused (camera off or wrong address?)") \
                        from None
                if isinstance(reason, TimeoutError) or "timed out" in str(reason):
                    raise ViscaTimeout(f"{self.base_url}{path}: no answer within {self.timeout:.1f} s") from None
                raise ViscaDisconnected(f"{self.base_url}: {getattr(reason, 'strerror', None) or reason}") from None
            except (TimeoutError, http.client.RemoteDisconnected, ConnectionError, http.client.HTTPException) as exc:
                raise ViscaTimeout(f"{self.base_url}{path}: {type(exc).__name__}") from None

        def before_retry(failures: int, error: BaseException) -> None:
            log.debug("retrying %s%s after: %s", self.base_url, path, error)

        policy = RetryPolicy(self.retries + 1, (ViscaTimeout, ViscaDisconnected, SonyCgiServerError), wait=0.05)
        return policy.call(attempt, before_retry)

    def visca_inquiry(self, packet: bytes, expect_len: int) -> bytes:
        """VISCA inquiry through ``visca-inquiry.cgi``; returns the reply's data bytes.

        A corrupted or unexpected reply is asked again (``retries`` times); an error reply raises."""

        def attempt(n: int) -> bytes:
            body = self.request("/command/visca-inquiry.cgi", {"visca": packet.hex().upper()})
            reply = _parse_hex_reply(body)
            if reply.kind is ReplyKind.ERROR:
                raise error_for(reply.error_code, reply.socket, "VISCA inquiry")
            if reply.kind is not ReplyKind.INQUIRY or len(reply.data) != expect_len \
                    or any(b & 0xF0 for b in reply.data):
                raise ViscaProtocolError(f"unexpected reply to VISCA inquiry: {body[:40]!r}")
            return reply.data

        return RetryPolicy(self.retries + 1, ViscaProtocolError).call(attempt)

    def visca_command(self, packet: bytes) -> None:
        """VISCA command through ``visca-ptzf.cgi`` (an error reply in the body raises)."""
        body = self.request("/command/visca-ptzf.cgi", {"visca": packet.hex().upper()})
        if body.strip():
            reply = _parse_hex_reply(body)
            if reply.kind is ReplyKind.ERROR:
                raise error_for(reply.error_code, reply.socket, "VISCA command")

    def ptzf(self, **fields: str) -> None:
        """``POST /command/ptzf.cgi`` with the given form fields."""
        self.request("/command/ptzf.cgi", form=fields)

    def snapshot(self) -> bytes:
        return self.request("/oneshotimage.jpg")


def _parse_hex_reply(body: bytes) -> Reply:
    text = body.decode("ascii", "replace").strip().replace(" ", "")
    try:
        packet = bytes.fromhex(text)
    except ValueError:
        raise ViscaProtocolError(f"camera body is not a hex VISCA reply: {text[:40]!r}") from None
    return parse_reply(packet)


class SonyCgiHead(HeadAdapter):
    """``fgloc.core.hardware.PanTiltHead`` for a Sony network camera over HTTP CGI (spec radians).

    ``poll_interval`` (s) paces the position/zoom polls; ``speed`` is the CGI speed 1..24.
    """

    unsteady_error = ViscaProtocolError

    def __init__(self, client: SonyCgiClient, units: PanTiltUnits | None = None, speed: int = 24,
                 poll_interval: float = 0.05, move_timeout_margin: float = 2.0, frames: FrameSourceArg = None) -> None:
        super().__init__(units or PanTiltUnits(SNC_RZ25N), frames, confirm_reads=True, max_reads=5,
                         read_gap_s=poll_interval)
        self.client = client
        if not 1 <= speed <= 24:
            raise SonyCgiError(f"speed must be 1..24, got {speed}")
        self.speed = speed
        self.poll_interval = poll_interval
        self.move_timeout_margin = move_timeout_margin

    @property
    def where(self) -> str:
        return self.client.base_url

    def read_counts_once(self) -> tuple[int, int]:
        """One position inquiry through the VISCA tunnel: (pan, tilt) signed device counts."""
        m = self.units.model
        data = self.client.visca_inquiry(cmd_pan_tilt_position_inquiry(1), m.pan_nibbles + 4)
        return decode_pan_tilt(data, m.pan_nibbles)

    def move_to_counts(self, pan: int, tilt: int) -> None:
        """AbsolutePanTilt, then poll until the read-back is the target (HTTP returns before the move ends)."""
        m = self.units.model
        self.check_counts(pan, tilt)
        start = self._last_counts or self.position_counts()
        self.client.ptzf(AbsolutePanTilt=f"{hex16(pan)},{hex16(tilt)},{self.speed}")
        expected = m.move_seconds(pan - start[0], tilt - start[1], self.speed, min(self.speed, m.max_tilt_speed))
        deadline = time.monotonic() + expected * 1.5 + self.move_timeout_margin
        while True:
            cur = self.read_counts_once()
            if cur == (pan, tilt):
                self._last_counts = cur
                return
            if time.monotonic() > deadline:
                self._last_counts = None
                raise ViscaTimeout(f"{self.client.base_url}: head did not reach ({pan}, {tilt}) counts "
                                   f"(last read {cur})")
            time.sleep(self.poll_interval)

    def set_zoom_counts(self, counts: int) -> None:
        """AbsoluteZoom, then poll until the read-back zoom is ``counts``."""
        self.client.ptzf(AbsoluteZoom=f"{counts:04X}")
        deadline = time.monotonic() + 5.0
        while self.zoom_counts() != counts:
            if time.monotonic() > deadline:
                raise ViscaTimeout(f"{self.client.base_url}: zoom did not reach {counts:04X}")
            time.sleep(self.poll_interval)

    def zoom_counts(self) -> int:
        return decode_zoom(self.client.visca_inquiry(cmd_zoom_position_inquiry(1), 4))

    def stop(self) -> None:
        m = self.units.model
        self.client.visca_command(cmd_pan_tilt_stop(1, m.max_pan_speed, min(m.max_tilt_speed, 0x14)))
        self._last_counts = None

    def home(self) -> None:
        self.client.visca_command(cmd_home(1))
        self._last_counts = None
        deadline = time.monotonic() + 10.0
        while self.position_counts() != (0, 0):
            if time.monotonic() > deadline:
                raise ViscaTimeout(f"{self.client.base_url}: head did not reach home")
            time.sleep(self.poll_interval)

    def _frame_without_source(self) -> np.ndarray:
        """No frame source: the camera's own JPEG snapshot."""
        import cv2

        jpeg = self.client.snapshot()
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise SonyCgiError(f"{self.client.base_url}/oneshotimage.jpg: not a JPEG image")
        return img


def open_cgi_head(url: str, units: PanTiltUnits | None = None, credentials: Credentials | None = None,
                  timeout: float = 2.0, retries: int = 2, **kw) -> SonyCgiHead:
    """A head for ``http://[user:pw@]HOST[:PORT]``; checks the camera answers a position inquiry."""
    head = SonyCgiHead(SonyCgiClient(url, credentials, timeout, retries), units, **kw)
    head.read_counts_once()
    return head
