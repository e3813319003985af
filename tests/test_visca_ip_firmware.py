"""VISCA over IP as SRG firmware does it: inquiries under payload type 01 00 are answered, replies can
go to a fixed controller port (52381), and the driver works with every variant."""

from __future__ import annotations

import json
import socket

import pytest

from fgloc.drivers.twins.visca_ip_camera import ViscaIpTwin
from fgloc.drivers.visca.codec import (
    cmd_pan_tilt_absolute,
    cmd_pan_tilt_position_inquiry,
    cmd_zoom_position_inquiry,
    decode_pan_tilt,
    decode_zoom,
)
from fgloc.drivers.visca.errors import ViscaError
from fgloc.drivers.visca.ip import (
    ERROR_MESSAGE_TYPE,
    TYPE_COMMAND,
    TYPE_CONTROL_REPLY,
    TYPE_INQUIRY,
    TYPE_REPLY,
    decode_message,
    encode_message,
    open_ip_head,
)
from fgloc.drivers.visca.session import Timeouts

H = bytes.fromhex
FAST = Timeouts(ack=0.1, inquiry=0.1, completion_margin=0.3, retries=3)
REPLY_PORT = 52381


def _client() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(1.0)
    return sock


def test_raw_client_gets_answers_to_01_00_inquiries() -> None:
    """A third-party client sends position and zoom inquiries as ``01 00``: the twin answers them
    (``01 11``, same sequence number) like SRG firmware, not with a message-type error."""
    with ViscaIpTwin() as twin:
        twin.emulator.set_pose(-1000, 200, 0x1234)
        with _client() as sock:
            sock.sendto(H("01 00 00 05 00 00 00 07 81 09 06 12 FF"), ("127.0.0.1", twin.port))
            reply = decode_message(sock.recv(64))
            assert (reply.payload_type, reply.sequence) == (TYPE_REPLY, 7)
            assert reply.payload == H("90 50 0F 0C 01 08 00 00 0C 08 FF")
            assert decode_pan_tilt(reply.payload[2:-1]) == (-1000, 200)
            sock.sendto(encode_message(TYPE_COMMAND, 8, cmd_zoom_position_inquiry(1)), ("127.0.0.1", twin.port))
            reply = decode_message(sock.recv(64))
            assert (reply.payload_type, reply.sequence, reply.payload) == (TYPE_REPLY, 8, H("90 50 01 02 03 04 FF"))
            assert decode_zoom(reply.payload[2:-1]) == 0x1234
            # Sony's own type 01 10 works as before; a *command* sent as an inquiry is still refused
            sock.sendto(encode_message(TYPE_INQUIRY, 9, cmd_pan_tilt_position_inquiry(1)), ("127.0.0.1", twin.port))
            assert decode_message(sock.recv(64)).payload[:2] == H("90 50")
            sock.sendto(encode_message(TYPE_INQUIRY, 10, cmd_pan_tilt_absolute(1, 0, 0)), ("127.0.0.1", twin.port))
            reply = decode_message(sock.recv(64))
            assert (reply.payload_type, reply.payload) == (TYPE_CONTROL_REPLY, ERROR_MESSAGE_TYPE)


@pytest.mark.parametrize("accepts", [(TYPE_INQUIRY, TYPE_COMMAND), (TYPE_INQUIRY,), (TYPE_COMMAND,)])
def test_driver_works_whichever_inquiry_type_the_camera_takes(accepts: tuple[int, ...]) -> None:
    """The driver sends 01 10 (Sony's document); a camera that takes inquiries only as 01 00 answers
    0F 02 once, and the link switches to 01 00 for good."""
    with ViscaIpTwin(inquiry_types=accepts) as twin, open_ip_head(twin.url, timeouts=FAST) as head:
        for target in [(100, -20), (-1200, 300)]:
            head.move_to_counts(*target)
            assert head.position_counts() == target
        link = head.session.link
        assert link.inquiry_type == (TYPE_COMMAND if accepts == (TYPE_COMMAND,) else TYPE_INQUIRY)
        assert head.session.stats.retries == 0


def test_fixed_reply_port_needs_the_drivers_local_port() -> None:
    """A camera that sends every reply to controller port 52381: without ``local_port`` the driver never
    hears it (one clear error naming the option); with it, moves and reads work."""
    with ViscaIpTwin(reply_port=REPLY_PORT) as twin:
        with pytest.raises(ViscaError, match="set reply_port"):
            open_ip_head(twin.url, timeouts=FAST)
        with open_ip_head(twin.url, timeouts=FAST, local_port=REPLY_PORT) as head:
            head.move_to_counts(300, 100)
            assert head.position_counts() == (300, 100)
            assert head.session.link._sock.getsockname()[1] == REPLY_PORT


def test_two_cameras_reply_to_the_same_controller_port() -> None:
    """Two such cameras on one controller: both links bind 52381, each gets only its own camera's replies."""
    with ViscaIpTwin(reply_port=REPLY_PORT) as a, ViscaIpTwin(reply_port=REPLY_PORT) as b, \
            open_ip_head(a.url, timeouts=FAST, local_port=REPLY_PORT) as ha, \
            open_ip_head(b.url, timeouts=FAST, local_port=REPLY_PORT) as hb:
        for k in range(5):
            ha.move_to_counts(10 * k, k)
            hb.move_to_counts(-20 * k, -k)
            assert ha.position_counts() == (10 * k, k) and hb.position_counts() == (-20 * k, -k)
        assert ha.session.stats.retries == 0 and hb.session.stats.retries == 0


def test_a_rig_with_reply_port_cameras_runs(tmp_path) -> None:
    """rig.json ``reply_port: 52381`` on two visca-ip cameras reaches the driver through
    fgloc.survey.session.open_hardware: both heads move and read back, the motes answer."""
    from fgloc.drivers.twins.rig import TwinCamera, TwinRig
    from fgloc.files.rig_config import parse_rig
    from fgloc.survey.session import open_hardware
    from tests.test_rig_config import EXAMPLE

    cams = [TwinCamera("cam0", "udp", model="VISCA-IP", reply_port=REPLY_PORT),
            TwinCamera("cam1", "udp", model="VISCA-IP", reply_port=REPLY_PORT)]
    with TwinRig(cams) as twins:
        data = json.loads(EXAMPLE.read_text())
        k = data["cameras"][0]["intrinsics"]
        data["cameras"] = [{"id": c.camera_id, "driver": "visca-ip", "port": twins.ports[c.camera_id],
                            "model": c.model, "intrinsics": k, "reply_port": REPLY_PORT} for c in cams]
        data["motes"] = {"driver": "tinyos-serial", "port": twins.mote_port, "addresses": {"n000": 5}}
        data["node_ids"] = ["n000"]
        data.pop("simulation", None)
        rig = parse_rig(data, "rig.json", EXAMPLE.parent)
        assert [c.reply_port for c in rig.cameras] == [REPLY_PORT, REPLY_PORT]
        opened = open_hardware(rig)
        try:
            for cid, target in (("cam0", (0.2, 0.1)), ("cam1", (-0.3, 0.05))):
                head = opened.open_head(cid)
                head.move_to(*target)
                pan, tilt = head.position()
                assert abs(pan - target[0]) < 0.01 and abs(tilt - target[1]) < 0.01
                head.close()
            assert opened.leds.set_led("n000", True) and twins.field.led_on.get(5) is True
        finally:
            opened.close()
        # the same rig without reply_port cannot hear those cameras: one clear error, not a hang
        for cam in data["cameras"]:
            del cam["reply_port"]
        opened = open_hardware(parse_rig(data, "rig.json", EXAMPLE.parent))
        try:
            with pytest.raises(ViscaError, match="set reply_port"):
                opened.open_head("cam0")
        finally:
            opened.close()


def test_rig_json_reply_port_is_checked() -> None:
    from fgloc.files.rig_config import RigConfigError, parse_rig
    from tests.test_rig_config import EXAMPLE

    base = json.loads(EXAMPLE.read_text())
    for value, problem in ((0, "reply_port"), (70000, "reply_port"), ("52381", "reply_port"), (1.5, "reply_port")):
        data = json.loads(json.dumps(base))
        data["cameras"][0]["driver"], data["cameras"][0]["port"] = "visca-ip", "udp://10.0.0.2"
        data["cameras"][0]["reply_port"] = value
        with pytest.raises(RigConfigError, match=rf"cameras\[0\]\.{problem}"):
            parse_rig(data, "rig.json", EXAMPLE.parent)
    data = json.loads(json.dumps(base))
    data["cameras"][0]["driver"], data["cameras"][0]["port"] = "visca-serial", "/dev/ttyUSB0"
    data["cameras"][0]["reply_port"] = REPLY_PORT  # on a serial camera: refused, naming the driver
    with pytest.raises(RigConfigError, match=r"cameras\[0\]\.reply_port: only for driver visca-ip, not visca-serial"):
        parse_rig(data, "rig.json", EXAMPLE.parent)


def test_a_late_completion_over_ip_is_dropped_by_its_sequence_number() -> None:
    """Over IP a Completion carries its request's sequence number: a late one of an abandoned command,
    arriving while a newer move runs on the same socket, is dropped by the link (no read-back needed)."""
    import threading
    import time

    from fgloc.drivers.visca.errors import ViscaTimeout

    with ViscaIpTwin(time_scale=1.0) as twin, open_ip_head(twin.url, timeouts=FAST) as head:
        head.position_counts()
        link = head.session.link
        head.session.timeouts.retries = 0
        with pytest.raises(ViscaTimeout):
            head.session.command(cmd_pan_tilt_absolute(1, 1440, 0, 0x0C, 0x0C), completion_timeout=0.05)
        abandoned = link._sequence
        head.session.timeouts.retries = 3
        assert head.session.stray == {}  # sequence numbers make stray windows unnecessary
        head.settings.pan_speed = 0x0C
        head._last_counts = None
        done = threading.Event()
        thread = threading.Thread(target=lambda: (head.move_to_counts(150, 0), done.set()))
        stale_before = link.stale
        thread.start()
        time.sleep(0.1)  # the 0.47 s move is under way
        twin._sock.sendto(encode_message(TYPE_REPLY, abandoned, H("90 51 FF")), link._sock.getsockname())
        time.sleep(0.1)
        assert not done.is_set()  # not fooled by the late Completion
        thread.join(timeout=5.0)
        assert done.is_set() and link.stale > stale_before
        assert head.read_counts_once() == (150, 0)
