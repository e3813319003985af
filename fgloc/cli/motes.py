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
    code = act.add_parser("code", help="start or stop coded blink sequences (docs/blink-codes.md)")
    code.add_argument("state", choices=["start", "stop"])
    code.add_argument("--count", type=int, default=None,
                      help="start: motes in the code book; addresses FIRST..FIRST+COUNT-1 take words 0..COUNT-1")
    code.add_argument("--first", type=int, default=1, help="address of book word 0 (default 1)")
    code.add_argument("--node", default=None,
                      help="only this node (unicast, confirmed by its report); default: broadcast to all")
    code.add_argument("--bit-period", type=float, default=1001.0 / 60000.0,
                      help="seconds per bit (default one NTSC field, 16.68 ms)")
    code.add_argument("--cycles", type=int, default=0, help="word repeats, 0 = until stopped")
    code.add_argument("--wait", type=float, default=1.0, help="broadcast: seconds to collect the nodes' reports")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fgloc.drivers.tinyos.network import open_mote_network

    if args.timeout <= 0 or args.attempts < 1:
        raise FglocError("motes: --timeout must be > 0 and --attempts >= 1")
    if "://" in args.port and not args.port.startswith("tcp://"):
        raise FglocError(f"--port {args.port}: motes need a serial device or tcp://HOST:PORT (SerialForwarder)")
    if args.action == "code":
        _check_code_args(args)
    net = open_mote_network(args.port, report_timeout=args.timeout, attempts=args.attempts, baudrate=args.baud)
    try:
        if args.action == "code":
            return _code(net, args)
        on = args.state == "on"
        if not net.set_led(args.node, on):
            raise FglocError(f"node {args.node}: no LED report after {args.attempts} tries "
                             "(node off, out of radio range, or wrong id)")
        print(f"node {args.node}: LED {args.state} (confirmed by the node)")
    finally:
        net.close()
    return 0


def _check_code_args(args: argparse.Namespace) -> None:
    from fgloc.drivers.tinyos.blink import MAX_CODE_BITS

    if args.state == "start" and (args.count is None or args.count < 1):
        raise FglocError(f"--count: start needs the number of motes in the book, >= 1 ({args.count})")
    if not 0 <= args.first <= 0xFFFE:
        raise FglocError(f"--first: mote address must be 0..65534 ({args.first})")
    if not 1e-5 <= args.bit_period <= 0.65535:
        raise FglocError(f"--bit-period: must be 10 us .. 0.655 s ({args.bit_period})")
    if not 0 <= args.cycles <= 0xFFFF:
        raise FglocError(f"--cycles: must be 0..65535 ({args.cycles})")
    if args.wait <= 0:
        raise FglocError(f"--wait: must be > 0 ({args.wait})")
    if args.state == "start":
        from fgloc.camera.blink_codes import code_book

        if args.first + args.count > 0xFFFF:
            raise FglocError(f"--count: addresses {args.first}..{args.first + args.count - 1} exceed 65534")
        if code_book(args.count).length > MAX_CODE_BITS:  # CodeBookError (an FglocError) when too many motes
            raise FglocError(f"--count: more motes than a {MAX_CODE_BITS}-bit book holds ({args.count})")


def _code(net: object, args: argparse.Namespace) -> int:
    from fgloc.camera.blink_codes import code_book
    from fgloc.drivers.tinyos.blink import BlinkBroadcast, BlinkCommand
    from fgloc.drivers.tinyos.messages import node_address
    from fgloc.drivers.tinyos.network import MoteNetwork

    assert isinstance(net, MoteNetwork)
    if args.state == "stop":
        if args.node is not None:
            if not net.stop_code(args.node):
                raise FglocError(f"node {args.node}: no blink report after {args.attempts} tries "
                                 "(node off, out of radio range, or wrong id)")
            print(f"node {args.node}: stopped (confirmed by the node)")
            return 0
        got = net.broadcast_codes(BlinkCommand(start=False), None, args.wait)
        print(f"stop sent; {len(got)} node(s) reported stopped: {' '.join(str(n) for n in sorted(got)) or '-'}")
        return 0
    book = code_book(args.count)
    cmd = BlinkBroadcast(book.length, args.first, args.count, args.bit_period, args.cycles)
    if args.node is not None:
        addr = node_address(args.node, None)
        k = cmd.word_index(addr)
        if k is None:
            raise FglocError(f"--node {args.node}: address {addr} not in {args.first}..{args.first + args.count - 1}")
        word = book.words[k]
        if not net.start_code(args.node, book.length, word, args.bit_period, args.cycles):
            raise FglocError(f"node {args.node}: no blink report after {args.attempts} tries "
                             "(node off, out of radio range, or wrong id)")
        print(f"node {args.node}: running word {k} = {word:#0{2 + (book.length + 3) // 4}x} "
              f"({book.length} bits, confirmed by the node)")
        return 0
    expect = set(range(args.first, args.first + args.count))
    got = net.broadcast_codes(cmd, expect, args.wait)
    wrong = sorted(a for a, rep in got.items() if rep != (True, book.length, _word(book.words, cmd.word_index(a))))
    silent = sorted(expect - set(got))
    print(f"started {args.count} motes on the {book.length}-bit book (addresses {args.first}.."
          f"{args.first + args.count - 1}); {len(got) - len(wrong)} confirmed, {len(silent)} silent, "
          f"{len(wrong)} wrong word")
    if silent:
        print(f"silent (start them with --node): {' '.join(str(a) for a in silent[:50])}"
              f"{' ...' if len(silent) > 50 else ''}")
    return 0 if not wrong else 2


def _word(words: tuple[int, ...], index: int | None) -> int | None:
    return None if index is None else words[index]
