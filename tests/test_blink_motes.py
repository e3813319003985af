"""``fgloc motes code``: start and stop coded blink sequences against the base-station twin (serial pty)."""

from __future__ import annotations

import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.cli import main
from fgloc.drivers.tinyos.blink import AM_BLINK_CODE, BlinkBroadcast, parse_blink_command
from fgloc.drivers.twins.base_station import BaseStationSerialTwin, MoteFieldEmulator


def test_broadcast_start_runs_each_motes_book_word_and_stop(capsys: pytest.CaptureFixture[str]) -> None:
    field = MoteFieldEmulator(nodes=range(1, 13), silent=[7])
    book = code_book(12)
    with BaseStationSerialTwin(field) as twin:
        assert main(["motes", "--port", twin.port, "code", "start", "--count", "12", "--wait", "0.5"]) == 0
        out = capsys.readouterr().out
        assert "11 confirmed, 1 silent, 0 wrong word" in out and "silent (start them with --node): 7" in out
        # one broadcast on the wire, not 12 unicasts; each node runs word address - 1 of the book
        cmds = [p for p in field.received if p.am_type == AM_BLINK_CODE]
        assert len(cmds) == 1 and cmds[0].dest == 0xFFFF
        assert parse_blink_command(cmds[0]) == BlinkBroadcast(book.length, 1, 12, 0.01668)  # 10 us units
        assert field.blink.running == {a: (book.length, book.words[a - 1]) for a in range(1, 13) if a != 7}
        assert main(["motes", "--port", twin.port, "code", "stop", "--node", "n003"]) == 0
        assert "node n003: stopped" in capsys.readouterr().out and 3 not in field.blink.running
        assert main(["motes", "--port", twin.port, "code", "stop", "--wait", "0.3"]) == 0
        # every present node answers a stop, the already stopped n003 too; silent 7 does not
        assert "11 node(s) reported stopped: 1 2 3 4 5 6 8 9 10 11 12" in capsys.readouterr().out
        assert field.blink.running == {}


def test_unicast_start_of_one_node_and_errors(capsys: pytest.CaptureFixture[str]) -> None:
    field = MoteFieldEmulator(silent=[9])
    book = code_book(100)
    with BaseStationSerialTwin(field) as twin:
        assert main(["motes", "--port", twin.port, "code", "start", "--count", "100", "--node", "n005"]) == 0
        assert "confirmed by the node" in capsys.readouterr().out
        assert field.blink.running == {5: (16, book.words[4])}
        assert main(["motes", "--port", twin.port, "--timeout", "0.05", "code", "start", "--count", "100",
                     "--node", "n009"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "no blink report" in err
        assert main(["motes", "--port", twin.port, "code", "start", "--count", "100", "--node", "n200"]) == 2
        assert "not in 1..100" in capsys.readouterr().err
    for bad, field_name in [(["--count", "0"], "--count"), (["--count", "70000"], "--count"),
                            (["--count", "5", "--bit-period", "2"], "--bit-period"),
                            (["--count", "5", "--cycles", "-1"], "--cycles")]:
        assert main(["motes", "--port", "/dev/null-x", "code", "start", *bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and field_name in err
