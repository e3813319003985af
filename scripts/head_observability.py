"""Fisher rank of the head parameters per scene type (planar / 3d, 2 and more cameras). Seeded.

For each scene: the rank of each parameter group's information (poses and nodes
eliminated, no prior), the rank of all 7 parameters of every camera together,
and the data-only standard deviation of each parameter relative to the typical
error size (below 1: the survey sees an error of that size; above: only the prior
holds it). Prints the markdown table of docs/head-calibration.md.

    .venv/bin/python scripts/head_observability.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from fgloc.core.head_model import DEFAULT_PRIOR_SIGMAS, HEAD_DIM, HEAD_PARAMETERS  # noqa: E402
from fgloc.core.model import NodeMode, Survey  # noqa: E402
from fgloc.init.start import InitialEstimate  # noqa: E402
from fgloc.sim.head_errors import TYPICAL_MAGNITUDES  # noqa: E402
from fgloc.sim.scenes import PaperScenario, RandomScene, paper_scenario, random_scene  # noqa: E402
from fgloc.solve.self_calibration import (  # noqa: E402
    RANK_TOL,
    build_self_calibration_problem,
    head_information,
    head_observability,
)


def scenes() -> list[tuple[str, Survey]]:
    out = [(f"paper planar, 2 cameras, h = {h}", paper_scenario(PaperScenario(heights=(h, h), seed=3)))
           for h in (0.1, 0.3)]
    out.append(("paper planar, 2 cameras, 9 nodes", paper_scenario(PaperScenario(n_nodes=9, heights=(0.3, 0.3),
                                                                                 seed=2))))
    for mode in (NodeMode.PLANAR, NodeMode.THREE_D):
        for n_cam in (2, 3, 4):
            s = random_scene(RandomScene(n_cameras=n_cam, n_nodes=100, mode=mode, visibility=1.0, ceiling_share=0.0,
                                         height_range=(0.3, 0.6), seed=3))
            out.append((f"random {mode.value}, {n_cam} cameras", s))
    return out


def main() -> None:
    print("| scene | group ranks (each camera) | joint rank / size | data std / typical error, worst camera |")
    print("|---|---|---|---|")
    for name, s in scenes():
        est = InitialEstimate(cameras=dict(s.truth.cameras), nodes=dict(s.truth.nodes))  # type: ignore[union-attr]
        ranks, std = head_observability(s, est)
        problem = build_self_calibration_problem(s, est, {c: tuple(range(HEAD_DIM)) for c in s.camera_ids},
                                                 with_prior=False)
        info, labels = head_information(problem, problem.initial)
        scale = np.array([DEFAULT_PRIOR_SIGMAS[i] for _, i in labels])
        w = np.linalg.eigvalsh(info * np.outer(scale, scale))
        joint = int(np.sum(w > RANK_TOL * max(w.max(), 1e-300)))
        groups = sorted({tuple(sorted(r.items())) for r in ranks.values()})
        group_text = "; ".join(", ".join(f"{k} {v}" for k, v in g) for g in groups)
        worst = np.max([v / TYPICAL_MAGNITUDES for v in std.values()], axis=0)
        std_text = ", ".join(f"{p} {'∞' if not np.isfinite(x) else f'{x:.2g}'}" for p, x in zip(HEAD_PARAMETERS, worst))
        print(f"| {name} | {group_text} | {joint} / {len(labels)} | {std_text} |")


if __name__ == "__main__":
    main()
