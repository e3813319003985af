#!/usr/bin/env python3
"""Replay a recorded survey journal node by node, showing the estimates as they would have evolved.

An example to start from, written only against fgloc's public API:

    python scripts/replay_survey.py my-survey/journal.jsonl --every 10 -o replayed-result.json

Reads the journal (a torn last line from a crash is ignored), feeds the nodes to
the estimator in the order they were surveyed, prints each estimate, and writes
the final estimate as a result.json.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from fgloc.core.errors import FglocError
from fgloc.files.journal import journal_to_survey, read_journal
from fgloc.files.survey_result import write_result
from fgloc.survey.live import MIN_SHARED_NODES, BatchEstimator, LiveEstimate, format_estimate


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("journal", help="journal.jsonl (or a survey directory holding one)")
    p.add_argument("--every", type=int, default=10, help="solve after every N nodes (default 10)")
    p.add_argument("-o", "--output", help="write the final estimate to this result.json")
    args = p.parse_args(argv)
    path = args.journal.rstrip("/")
    if not path.endswith(".jsonl"):
        path += "/journal.jsonl"
    try:
        state = read_journal(path)
        full = journal_to_survey(state)
        estimator = BatchEstimator()
        order = [n for n in state.started if n in state.done] or list(full.node_ids)
        final = None
        for k in range(1, len(order) + 1):
            if k % args.every and k != len(order):
                continue
            included = set(order[:k])
            partial = replace(full, observations=[o for o in full.observations if o.node in included])
            shared = {o.node for o in partial.observations if o.camera == full.gauge.baseline} & \
                     {o.node for o in partial.observations if o.camera == full.gauge.origin}
            if len(shared) < MIN_SHARED_NODES:
                continue
            result = estimator.update(partial)
            final = LiveEstimate(k, partial, result, 0.0)
            print(format_estimate(final, limit=3), flush=True)
    except FglocError as exc:
        print(f"replay_survey: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if final is None:
        print("replay_survey: error: too few nodes seen by both gauge cameras to solve", file=sys.stderr)
        return 2
    if args.output:
        write_result(final.result, args.output)
    print(f"replayed {len(order)} nodes, {len(full.observations)} observations; "
          f"{len(final.result.nodes)} localized, {len(final.result.unlocalized)} unlocalized")
    return 0


if __name__ == "__main__":
    sys.exit(main())
