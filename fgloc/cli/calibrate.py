"""``fgloc calibrate``: camera intrinsics from checkerboard images, written to camera.json."""

from __future__ import annotations

import argparse
import logging


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="calibrate camera intrinsics from checkerboard images",
        description="Find the checkerboard in each image, calibrate (OpenCV), reject images with a "
        "large reprojection error and write the model (docs/camera-model.md).",
    )
    p.add_argument("images", nargs="+", help="checkerboard images, all at one zoom and resolution")
    p.add_argument("-o", "--output", required=True, help="camera.json to write")
    p.add_argument("--board", required=True, help="inner corners as COLSxROWS, e.g. 9x6")
    p.add_argument("--square", type=float, required=True, help="square side (any unit; does not affect intrinsics)")
    p.add_argument("--zoom", type=float, default=0.0, help="zoom fraction the images were taken at (0 = widest, default)")
    p.add_argument("--max-image-rms", type=float, default=0.5,
                   help="reject images above this RMS reprojection error (px) when also 3x the median (default 0.5)")
    p.add_argument("--fit-k3", action="store_true", help="also fit the k3 radial term (default: fixed at 0)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fgloc.camera.calibration import BoardSpec, CalibrationError, calibrate
    from fgloc.camera.led_measurement import ZOOM_TOLERANCE
    from fgloc.cli._args import finite
    from fgloc.cli._output import StepBar
    from fgloc.files.camera_file import write_intrinsics

    log = logging.getLogger(__name__)
    board = BoardSpec.parse(args.board, args.square)
    if not 0.0 <= args.zoom <= 1.0:
        raise CalibrationError(f"--zoom: must lie in [0, 1], got {args.zoom!r}")
    from fgloc.camera.image_files import read_gray

    finite("--max-image-rms", args.max_image_rms, above=0.0)
    images, unreadable = [], []
    for name in args.images:
        image, problem = read_gray(name)
        if image is None:  # named in the table below, or in the refusal
            unreadable.append((name, problem))
        else:
            images.append((name, image))
    if not images:
        raise CalibrationError(f"{unreadable[0][0]}: {unreadable[0][1]}" + (
            f" (and the {len(unreadable) - 1} other images are unreadable too)" if len(unreadable) > 1 else ""))
    if args.zoom > ZOOM_TOLERANCE:
        log.warning(
            f"calibrating at zoom {args.zoom:.3f}: only the widest zoom (0) keeps the optical "
            "centre on the pan/tilt axes; bearings measured at this zoom carry a parallax error"
        )
    with StepBar(args.progress, "calibrate", unit="image") as bar:
        result = calibrate(images, board, zoom=args.zoom, max_image_rms=args.max_image_rms, fit_k3=args.fit_k3,
                           progress=bar, unreadable=unreadable)
    width = max(len(r.name) for r in result.reports)
    print(f"{'image':<{width}}  {'rms px':>8}  status")
    for r in result.reports:
        rms = "-" if r.rms_px is None else f"{r.rms_px:.3f}"
        print(f"{r.name:<{width}}  {rms:>8}  {r.reason}")
    i = result.intrinsics
    used = sum(r.used for r in result.reports)
    print(
        f"used {used} of {len(result.reports)} images, RMS {result.rms_px:.3f} px: fx {i.fx:.2f} fy {i.fy:.2f} "
        f"cx {i.cx:.2f} cy {i.cy:.2f} k1 {i.k1:.4f} k2 {i.k2:.4f} p1 {i.p1:.5f} p2 {i.p2:.5f} k3 {i.k3:.4f}"
    )
    write_intrinsics(i, args.output)
    print(f"wrote {args.output}")
    return 0
