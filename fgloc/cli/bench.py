"""``fgloc bench``: the benchmark suite (see :mod:`fgloc.evaluate.bench`)."""

from __future__ import annotations

import argparse

DESCRIPTION = "Every solver method on every scene, side by side: stage medians, growth with n, peak memory."


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmark the solver against GTSAM's C++ factors and scipy",
                       description=DESCRIPTION)
    p.add_argument("--quick", action="store_true", help="small scenes, 2 repeats (seconds, for tests)")
    p.add_argument("--json", metavar="FILE", help="also write the raw results as JSON")
    p.add_argument("--methods", default="fgloc,fgloc_reference,gtsam_cpp,numpy_schur,scipy,subset_newton", help="comma-separated methods")
    p.add_argument("--cases", help="comma-separated NODESxCAMERAS, e.g. 100x2,1000x8 (default: 100x2 ... 100000x8)")
    p.add_argument("--scipy-max-nodes", type=int, help="skip scipy above this many nodes (default 1000; 80 with --quick)")
    p.add_argument("--incremental", default=None, help="iSAM2 cases NODESxCAMERAS (default 1000x8,10000x8; 'none' to skip)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fgloc.cli._output import StepBar
    from fgloc.core.errors import FglocError
    from fgloc.evaluate.bench import FULL_CASES, QUICK_CASES, json_safe, parse_cases, run_benchmark
    from fgloc.evaluate.bench_methods import METHODS
    from fgloc.files.json_io import write_json_atomic

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise FglocError(f"--methods: unknown method {bad[0]!r} (known: {', '.join(METHODS)})")
    cases = parse_cases(args.cases) if args.cases else (QUICK_CASES if args.quick else FULL_CASES)
    scipy_max = args.scipy_max_nodes if args.scipy_max_nodes is not None else (80 if args.quick else 1000)
    inc_spec = args.incremental or ("200x4" if args.quick else "1000x8,10000x8")
    inc_cases = [] if inc_spec == "none" else parse_cases(inc_spec)
    with StepBar(args.progress, "bench", unit="case") as bar:
        report = run_benchmark(cases, methods, args.quick, scipy_max, inc_cases, progress=bar)
    print(report["markdown"])
    if args.json:
        write_json_atomic(json_safe(report), args.json)
    return 0
