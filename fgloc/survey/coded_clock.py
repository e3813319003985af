"""Survey-clock bookkeeping for a running survey: device operations become clock operations.

:class:`ClockSink` collects, per camera lane, the :mod:`fgloc.survey.clock` operations
the survey performs while it is ``active``; :class:`ClockedHeadProxy` wraps any
:class:`~fgloc.core.hardware.PanTiltHead` and reports each move (a :class:`Slew` from
where the head was told to be last, then a :class:`Settle`), position read and frame
grab to the sink before doing it; :class:`CountingLeds` counts LED commands (radio).
Nothing here sleeps or changes what the devices do. Angles radians, times seconds.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.survey.clock import (
    EVI_D100,
    HEAD_MODELS,
    FieldTime,
    Frames,
    Op,
    PositionRead,
    Radio,
    RigTiming,
    Settle,
    Slew,
    Wait,
    parallel,
    price,
)


def rig_timing(model: str) -> RigTiming:
    """Clock model of a camera model name (case-insensitive); models without a clock model
    are priced as an EVI-D100 (an assumption, docs/survey.md)."""
    by_name = {k.lower(): v for k, v in HEAD_MODELS.items()}
    return RigTiming(head=by_name.get(model.lower(), EVI_D100))


class ClockSink:
    """Clock operations per camera lane, collected while :attr:`active` (thread-safe)."""

    def __init__(self, camera_ids: list[str]) -> None:
        self.ops: dict[str, list[Op]] = {c: [] for c in camera_ids}
        self.where: dict[str, tuple[float, float]] = {}
        self.active = False
        self.lock = threading.Lock()

    def add(self, camera: str, *ops: Op) -> None:
        if self.active:
            with self.lock:
                self.ops[camera].extend(ops)

    def take(self) -> dict[str, list[Op]]:
        """The operations collected so far, per camera; the sink starts empty again."""
        with self.lock:
            out, self.ops = self.ops, {c: [] for c in self.ops}
        return out


class ClockedHeadProxy:
    """A head that reports its operations to a :class:`ClockSink`, then performs them."""

    def __init__(self, head: PanTiltHead, camera: str, sink: ClockSink) -> None:
        self._head = head
        self._camera = camera
        self._sink = sink

    def move_to(self, pan: float, tilt: float) -> None:
        last = self._sink.where.get(self._camera, (0.0, 0.0))
        self._sink.add(self._camera, Slew.between(last, (pan, tilt)), Settle())
        self._head.move_to(pan, tilt)
        self._sink.where[self._camera] = (pan, tilt)

    def position(self) -> tuple[float, float]:
        self._sink.add(self._camera, PositionRead())
        return self._head.position()

    def grab_frame(self) -> np.ndarray:
        self._sink.add(self._camera, Frames(1))
        return self._head.grab_frame()

    def _move_and_zoom(self, pan: float, tilt: float, zoom: float) -> None:
        if self._sink.active:  # priced inside a node: the zoom travel runs with the move
            last = self._sink.where.get(self._camera, (0.0, 0.0))
            self._sink.add(self._camera, Slew.between(last, (pan, tilt), zoom - float(self._head.zoom())), Settle())
        self._head.move_and_zoom(pan, tilt, zoom)  # type: ignore[attr-defined]
        self._sink.where[self._camera] = (pan, tilt)

    def __getattr__(self, name: str) -> Any:  # set_zoom, zoom, stop, home, close, driver extras
        if name == "move_and_zoom" and callable(getattr(self._head, name, None)):
            return self._move_and_zoom  # only a head that zooms while moving has it (coded.zooms_while_moving)
        return getattr(self._head, name)


def clocked_opener(open_head: Callable[[str], PanTiltHead], sink: ClockSink) -> Callable[[str], PanTiltHead]:
    """``open_head`` whose heads report to ``sink``."""
    return lambda camera: ClockedHeadProxy(open_head(camera), camera, sink)  # type: ignore[return-value]


class CountingLeds:
    """An LED controller that counts the commands it sends (``commands``; radio time)."""

    def __init__(self, leds: LedController) -> None:
        self._leds = leds
        self.commands = 0

    def set_led(self, node_id: str, on: bool) -> bool:
        self.commands += 1
        return self._leds.set_led(node_id, on)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._leds, name)


def node_field_time(ops: dict[str, list[Op]], led_commands: int, led_wait_s: float,
                    timing: dict[str, RigTiming]) -> FieldTime:
    """Field time of one sequentially measured node: its LED commands (acknowledged radio
    commands) and the LED wait, then every camera's operations in parallel (the longest lane)."""
    first = timing[next(iter(timing))]
    lanes = [price(ops.get(c, []), t) for c, t in timing.items()]
    return price([Radio(unicast=led_commands), Wait(led_wait_s)], first) + parallel(lanes)


class SequentialClock:
    """Prices a sequential survey node by node on the survey clock (nothing sleeps).

    :attr:`open_head` and :attr:`leds` are the runner's devices wrapped so that every
    move, position read, frame and LED command is recorded; :meth:`begin` and :meth:`end`
    bracket one node (or the repeat phase) and return its :class:`FieldTime`: the LED
    commands and wait, then the cameras' lanes in parallel (:func:`node_field_time`).
    """

    def __init__(self, rig: Any, open_head: Callable[[str], PanTiltHead], leds: LedController) -> None:
        self.sink = ClockSink(list(rig.camera_ids))
        self.open_head = clocked_opener(open_head, self.sink)
        self.leds = CountingLeds(leds)
        self.timing = {c.id: rig_timing(c.model) for c in rig.cameras}
        self.led_wait_s = float(rig.search.led_wait_s)
        self._before = 0

    def begin(self) -> None:
        self.sink.take()
        self.sink.active, self._before = True, self.leds.commands

    def end(self) -> FieldTime:
        self.sink.active = False
        return node_field_time(self.sink.take(), self.leds.commands - self._before, self.led_wait_s, self.timing)
