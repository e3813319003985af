#!/usr/bin/env python3
"""Driver round-trip costs against the byte-level twins, fault-free vs faulty, side by side.

Prints a table of median wall time per operation (ms) over REPEATS runs of N
operations each: VISCA serial move+read-back, VISCA-IP move+read-back, Sony CGI
move+read-back, TinyOS LED on (serial and SerialForwarder). Twins run with
instantaneous motion (time_scale 0), so the numbers are protocol + retry cost on
this machine, not camera motion. Faulty = 5 % dropped replies + 1 % corrupted bytes.

    .venv/bin/python scripts/bench_drivers.py [--n 30] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

from fgloc.drivers.sony_cgi import open_cgi_head
from fgloc.drivers.tinyos.network import open_mote_network
from fgloc.drivers.twins.base_station import BaseStationSerialTwin, SerialForwarderTwin
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.sony_cgi_camera import SonyCgiTwin
from fgloc.drivers.twins.visca_camera import ViscaSerialTwin
from fgloc.drivers.twins.visca_ip_camera import ViscaIpTwin
from fgloc.drivers.visca.head import open_serial_head
from fgloc.drivers.visca.ip import open_ip_head
from fgloc.drivers.visca.session import Timeouts

TIMEOUTS = Timeouts(ack=0.1, inquiry=0.1, completion_margin=0.2, retries=6)


def _moves(head, n: int) -> None:
    for k in range(n):
        target = ((k * 97) % 2000 - 1000, (k * 31) % 600 - 300)
        head.move_to_counts(*target)
        assert head.position_counts() == target


def _leds(net, n: int) -> None:
    for k in range(n):
        assert net.set_led(f"n{k}", True)


def bench(kind: str, faults: FaultConfig | None, n: int) -> tuple[float, dict]:
    if kind == "visca-serial":
        with ViscaSerialTwin(faults=faults) as twin, open_serial_head(twin.port, timeouts=TIMEOUTS) as head:
            t0 = time.perf_counter()
            _moves(head, n)
            return time.perf_counter() - t0, dict(twin.faults.counts)
    if kind == "visca-ip":
        with ViscaIpTwin(faults=faults) as twin, open_ip_head(twin.url, timeouts=TIMEOUTS) as head:
            t0 = time.perf_counter()
            _moves(head, n)
            return time.perf_counter() - t0, dict(twin.faults.counts)
    if kind == "sony-cgi":
        with SonyCgiTwin(faults=faults) as twin, \
                open_cgi_head(twin.url, timeout=0.2, retries=6, poll_interval=0.005) as head:
            t0 = time.perf_counter()
            _moves(head, n)
            return time.perf_counter() - t0, dict(twin.faults.counts)
    if kind == "tinyos-serial":
        with BaseStationSerialTwin(faults=faults) as twin, \
                open_mote_network(twin.port, ack_timeout=0.05, retries=8, report_timeout=0.1, attempts=6) as net:
            t0 = time.perf_counter()
            _leds(net, n)
            return time.perf_counter() - t0, dict(twin.faults.counts)
    if kind == "serial-forwarder":
        with SerialForwarderTwin(faults=faults) as twin, \
                open_mote_network(twin.url, report_timeout=0.1, attempts=6) as net:
            t0 = time.perf_counter()
            _leds(net, n)
            return time.perf_counter() - t0, dict(twin.faults.counts)
    raise ValueError(kind)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"{'driver':18} {'op':22} {'clean ms/op':>12} {'faulty ms/op':>13} {'ratio':>6}  faults injected (last run)")
    for kind in ("visca-serial", "visca-ip", "sony-cgi", "tinyos-serial", "serial-forwarder"):
        clean, faulty, counts = [], [], {}
        for r in range(args.repeats):
            clean.append(bench(kind, None, args.n)[0] / args.n * 1e3)
            t, counts = bench(kind, FaultConfig(drop_rate=0.05, byte_error_rate=0.01, seed=r), args.n)
            faulty.append(t / args.n * 1e3)
        c, f = statistics.median(clean), statistics.median(faulty)
        op = "LED on (confirmed)" if "serial-f" in kind or "tinyos" in kind else "move + read-back"
        print(f"{kind:18} {op:22} {c:12.2f} {f:13.2f} {f / c:6.1f}  {counts}")


if __name__ == "__main__":
    main()
