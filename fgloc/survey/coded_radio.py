"""The coded survey's mote radio: start the codes, pause and resume motes, stop.

One broadcast start by address (:class:`~fgloc.drivers.tinyos.blink.BlinkBroadcast`: the
mote at address ``first + k`` runs word k of the book), sent again while some mote has not
confirmed; pause-by-bitmap updates for radio separation
(:func:`~fgloc.drivers.tinyos.blink.pause_packets`); one stop broadcast. Each broadcast is
priced on the survey clock's radio phase; the start and stop are journaled (``codes``).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from fgloc.survey.clock import Radio, price
from fgloc.survey.runner import SurveyRunner

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey

logger = logging.getLogger(__name__)


def broadcast(coded: CodedSurvey, command: object, expect: set[int]) -> dict[int, tuple[bool, int, int]]:
    """Broadcast ``command``; the reports of the ``expect`` addresses (address -> (running,
    length, word)) collected for the settings' report wait. Priced as one broadcast."""
    got: dict[int, tuple[bool, int, int]] = coded.leds.broadcast_codes(command, expect, coded.settings.report_wait_s)
    coded.radio_s += price([Radio(broadcast=1)], coded.timing[coded.rig.camera_ids[0]]).total
    return got


def start_codes(coded: CodedSurvey, runner: SurveyRunner) -> None:
    """Start every mote's code (one broadcast, again for the motes that have not confirmed, up
    to the settings' ``start_attempts``) and journal the start with the silent motes."""
    from fgloc.drivers.tinyos.blink import BlinkBroadcast

    command = BlinkBroadcast(coded.book.length, coded.first, len(coded.book), coded.camera.frame_period_s)
    expect = set(coded.addresses.values())
    confirmed: set[int] = set()
    for _ in range(coded.settings.start_attempts):
        got = broadcast(coded, command, expect - confirmed)
        confirmed |= {a for a, (running, length, _) in got.items() if running and length == coded.book.length}
        if expect <= confirmed:
            break
    silent = sorted(n for n, a in coded.addresses.items() if a not in confirmed)
    coded.stats.confirmed = len(expect & confirmed)
    rec = {"type": "codes", "action": "start", "length": coded.book.length, "first": coded.first,
           "count": len(coded.book), "bit_period_s": command.bit_period_s, "confirmed": coded.stats.confirmed,
           "silent": silent}
    runner.journal.append(rec)
    runner.state.codes.append(rec)
    if silent:
        logger.warning(f"{len(silent)} motes did not confirm their code (first: {silent[0]}); "
                       "they are read the sequential way if no camera decodes them")


def pause_motes(coded: CodedSurvey, paused: set[int]) -> None:
    """Pause (LED dark, code running) the motes at ``paused`` addresses and resume the others:
    the pause-by-bitmap packets over the survey's address range, each broadcast
    ``PAUSE_REPEATS`` times (no report confirms a pause; a mote that missed all stays lit,
    and its blob stays ambiguous: refused, never guessed)."""
    from fgloc.drivers.tinyos.blink import pause_packets
    from fgloc.survey.coded_separation import PAUSE_REPEATS

    packets = pause_packets(paused, range(coded.first, max(coded.addresses.values()) + 1))
    for packet in packets:
        for _ in range(PAUSE_REPEATS):
            coded.leds.broadcast_codes(packet, set(), 0.0)
    coded.radio_s += price([Radio(broadcast=PAUSE_REPEATS * len(packets))], coded.timing[coded.rig.camera_ids[0]]).total
    coded.stats.pause_updates += 1


def stop_codes(coded: CodedSurvey, runner: SurveyRunner) -> None:
    """Stop every mote's code (one broadcast) and journal the stop."""
    from fgloc.drivers.tinyos.blink import BlinkCommand

    broadcast(coded, BlinkCommand(start=False), set())
    runner.journal.append({"type": "codes", "action": "stop"})
