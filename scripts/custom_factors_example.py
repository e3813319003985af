"""Add your own factors to fgloc's graph: a GPS anchor on one node and radio ranges.

Written only against the public API (``import fgloc``) and GTSAM. It simulates the
paper's survey, builds fgloc's factor graph, then adds

* a GPS-like anchor: a ``gtsam.PriorFactorPoint2`` on node n000's true ground
  position (1 mm sigma, in baseline units), and
* a radio range between n001 and n002: a ``gtsam.CustomFactor`` with error
  ``|p_a - p_b| - d`` and its analytic Jacobians,

solves, and prints how each node's uncertainty changed.

    python scripts/custom_factors_example.py
"""

from __future__ import annotations

import gtsam
import numpy as np

import fgloc


def range_factor(key_a: int, key_b: int, distance: float, sigma: float) -> gtsam.CustomFactor:
    """Distance between two planar nodes (Point2), e.g. from radio ranging, in baseline units."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        a, b = values.atPoint2(this.keys()[0]), values.atPoint2(this.keys()[1])
        d = np.asarray(a) - np.asarray(b)
        norm = float(np.linalg.norm(d))
        if H is not None:
            u = (d / norm).reshape(1, 2)
            H[0], H[1] = u, -u
        return np.array([norm - distance])

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, sigma), [key_a, key_b], error)


def main() -> dict[str, tuple[float, float]]:
    survey = fgloc.paper_scenario(fgloc.PaperScenario(n_nodes=50, seed=7))
    truth = survey.truth.nodes
    plain = fgloc.solve_survey(survey)

    problem = fgloc.build_problem(survey, fgloc.initialize(survey))
    anchor = problem.node_keys["n000"]
    problem.add_factor(gtsam.PriorFactorPoint2(anchor, truth["n000"][:2], gtsam.noiseModel.Isotropic.Sigma(2, 1e-3)))
    true_range = float(np.linalg.norm(truth["n001"] - truth["n002"]))
    problem.add_factor(range_factor(problem.node_keys["n001"], problem.node_keys["n002"], true_range, 1e-4))
    extended = fgloc.solve(problem)

    changes = {}
    print("node   std before (m at 100 m)   std after")
    for n in ("n000", "n001", "n002", "n010"):
        before = 100 * float(np.sqrt(np.trace(plain.nodes[n].covariance)))
        after = 100 * float(np.sqrt(np.trace(extended.nodes[n].covariance)))
        changes[n] = (before, after)
        print(f"{n}   {before:8.3f}                  {after:8.3f}")
    d = np.linalg.norm(extended.nodes["n001"].position - extended.nodes["n002"].position)
    print(f"range n001-n002: solved {d:.6f}, measured {true_range:.6f}")
    return changes


if __name__ == "__main__":
    main()
