"""``fgloc score``: per-node error and covariance consistency against truth."""

from __future__ import annotations

import argparse
import json

from fgloc.core.errors import FglocError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("score", help="score a result against a simulated survey's truth")
    p.add_argument("survey", help="survey.json with truth")
    p.add_argument("result", help="result.json to score")
    p.add_argument("--baseline-m", type=float, default=100.0, help="baseline length in metres (default 100)")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fgloc.cli._args import finite
    from fgloc.evaluate.score import format_score_table, score
    from fgloc.files.survey_result import check_against_survey, read_result, read_survey

    finite("--baseline-m", args.baseline_m, above=0.0)
    survey = read_survey(args.survey)
    if survey.truth is None:
        raise FglocError(f"{args.survey}: truth: missing (only simulated surveys can be scored)")
    result = read_result(args.result)
    check_against_survey(result, survey, args.result, args.survey)
    s = score(survey, result, args.baseline_m)
    print(json.dumps(s.as_dict(), indent=1) if args.json else format_score_table(s, args.baseline_m))
    return 0
