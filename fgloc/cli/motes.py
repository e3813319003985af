"""``fgloc motes``: switch a mote's LED through the base station (TinyOS 2 serial or SerialForwarder)."""

from __future__ import annotations

import argparse

from fgloc.core.errors import FglocError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("motes", help="talk to the mote network's base station")
    p.add_argument("--port", required=True,
                   help="base station serial device (TinyOS 2, 57600 bit/s) or tcp://HOST[:PORT] (SerialForwarder)")
    p.add_argument("--baud", type=int, default=57600, help="serial bit rate (default 57600, MicaZ)")
    p.add_argument("--timeout", type=float, default=0.5, help="seconds to wait for the node's LED report")
    p.add_argument("--attempts", type=int, default=3, help="LED command sends before giving up (default 3)")
    act = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    led = act.add_parser("led", help="switch NODE's LEDs on or off and wait for its report")
    led.add_argument("node", help="node id (n005, 5, ...): its trailing number is the mote address")
    led.add_argument("state", choices=["on", "off"])
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fgloc.drivers.tinyos.network import open_mote_network

    if args.timeout <= 0 or args.attempts < 1:
        raise FglocError("motes: --timeout must be > 0 and --attempts >= 1")
    if "://" in args.port and not args.port.startswith("tcp://"):
        raise FglocError(f"--port {args.port}: motes need a serial device or tcp://HOST:PORT (SerialForwarder)")
    net = open_mote_network(args.port, report_timeout=args.timeout, attempts=args.attempts, baudrate=args.baud)
    try:
        on = args.state == "on"
        if not net.set_led(args.node, on):
            raise FglocError(f"node {args.node}: no LED report after {args.attempts} tries "
                             "(node off, out of radio range, or wrong id)")
        print(f"node {args.node}: LED {args.state} (confirmed by the node)")
    finally:
        net.close()
    return 0
