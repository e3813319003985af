"""``fgloc view``: show a result (and optionally its survey) in Rerun, or save it as an .rrd."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from fgloc.core.errors import FglocError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="show a result in the Rerun viewer, or save it as an .rrd")
    p.add_argument("result", help="result.json to show")
    p.add_argument("--survey", help="its survey.json: adds bearing rays, truth and error segments")
    p.add_argument("--save", metavar="FILE.rrd", help="write the recording here instead of opening a viewer")
    p.add_argument("--screenshot", metavar="FILE.png",
                   help="render the default layout headless to a PNG (needs a Vulkan driver, e.g. Debian's "
                        "mesa-vulkan-drivers) instead of opening a viewer")
    p.add_argument("--size", default="1600x900", help="window size for --screenshot (default 1600x900)")
    p.add_argument("--bind", default="127.0.0.1",
                   help="address the viewer's server listens on (default 127.0.0.1, loopback only)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import fgloc.viz as viz  # rerun is imported only by this command
    from fgloc.files.survey_result import check_against_survey, read_result, read_survey
    from fgloc.survey.head_check import read_head_block

    result = read_result(args.result)
    survey = read_survey(args.survey) if args.survey else None
    if survey is not None:
        check_against_survey(result, survey, args.result, args.survey)
    if not (args.save or args.screenshot) and not viz.has_display():
        raise FglocError(f"{args.result}: no display to show the viewer on (DISPLAY is unset); "
                         "use --save FILE.rrd and open that file where there is a screen (`rerun FILE.rrd`)")
    cam_cov = viz.camera_covariances_or_none(survey, result)
    head = read_head_block(args.result)  # the head calibration of --head-model auto|full, if any
    if args.save:
        viz.write_rrd(args.save, result, survey, camera_covariances=cam_cov, head_calibration=head)
        print(f"wrote {args.save} (open it with `rerun {args.save}`)")
    if args.screenshot:
        with tempfile.TemporaryDirectory(prefix="fgloc-view-") as tmp:
            rrd = Path(args.save) if args.save else viz.write_rrd(Path(tmp) / "view.rrd", result, survey,
                                                                        camera_covariances=cam_cov,
                                                                        head_calibration=head)
            try:
                report = viz.render_headless(rrd, args.screenshot, window_size=args.size)
            except (RuntimeError, TimeoutError) as exc:
                raise FglocError(f"{args.screenshot}: headless render failed: {exc}") from None
        bad = {name: r for name, r in report.view_reports.items() if r}
        print(f"wrote {args.screenshot}" + (f"; view problems: {bad}" if bad else ""))
        return 0 if not bad else 1
    if args.save:
        return 0
    with tempfile.TemporaryDirectory(prefix="fgloc-view-") as tmp:
        path = Path(tmp) / "view.rrd"
        viz.write_rrd(path, result, survey, camera_covariances=cam_cov, head_calibration=head)
        return viz.view_rrd(path, bind=args.bind)
