"""``fgloc ptz``: drive one pan-tilt head by hand (position read-back, goto, zoom, home, stop).

Angles are degrees in the spec's convention (pan counter-clockwise seen from
above, tilt up); the driver converts counts, signs and mounting.
"""

from __future__ import annotations

import argparse
import math

from fgloc.core.errors import FglocError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ptz", help="read or move a pan-tilt camera head (VISCA serial, VISCA-over-IP, Sony CGI)")
    p.add_argument("--port", required=True,
                   help="serial device (VISCA RS-232), udp://HOST[:PORT] (VISCA over IP) or http://HOST (Sony CGI)")
    p.add_argument("--camera-model", default=None,
                   help="EVI-D100 (serial default), EVI-D30, EVI-D70, EVI-D80, SNC-RZ25N (http default), VISCA-IP")
    p.add_argument("--mount", default="desk", choices=["desk", "upright", "ceiling"],
                   help="head mounting; ceiling flips pan and tilt (default desk)")
    p.add_argument("--address", type=int, default=1, help="VISCA camera address on the serial chain (default 1)")
    p.add_argument("--timeout", type=float, default=0.3,
                   help="VISCA reply timeout in seconds (default 0.3; HTTP requests use at least 2 s)")
    p.add_argument("--retries", type=int, default=3, help="resends after a timeout (default 3)")
    act = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    act.add_parser("position", help="print pan and tilt in degrees")
    g = act.add_parser("goto", help="move to PAN TILT degrees and print the read-back position")
    g.add_argument("pan", type=float, help="pan in degrees (counter-clockwise from above)")
    g.add_argument("tilt", type=float, help="tilt in degrees (up positive)")
    z = act.add_parser("zoom", help="set zoom (0 wide .. 1 optical tele) and print the read-back")
    z.add_argument("fraction", type=float)
    act.add_parser("home", help="go to the device's home position and print it")
    act.add_parser("stop", help="stop motion and print the position")
    p.set_defaults(run=run)


def format_position(pan: float, tilt: float) -> str:
    return f"pan {math.degrees(pan):.3f} deg  tilt {math.degrees(tilt):.3f} deg"


def run(args: argparse.Namespace) -> int:
    from fgloc.drivers.connect import HeadOptions, open_head

    if args.timeout <= 0 or args.retries < 0:
        raise FglocError("ptz: --timeout must be > 0 and --retries >= 0")
    options = HeadOptions(camera_model=args.camera_model, mount=args.mount, address=args.address,
                          timeout=args.timeout, retries=args.retries)
    head = open_head(args.port, options)
    try:
        if args.action == "goto":
            if not (math.isfinite(args.pan) and math.isfinite(args.tilt)):
                raise FglocError(f"ptz goto: pan/tilt must be finite numbers, got {args.pan} {args.tilt}")
            head.move_to(math.radians(args.pan), math.radians(args.tilt))
        elif args.action == "zoom":
            head.set_zoom(args.fraction)
            print(f"zoom {head.zoom():.4f}")
            return 0
        elif args.action == "home":
            head.home()
        elif args.action == "stop":
            head.stop()
        print(format_position(*head.position()))
    finally:
        close = getattr(head, "close", None)  # every driver has one; the PanTiltHead protocol does not
        if close is not None:
            close()
    return 0
