"""MarginalizedNodes against dense linear algebra on a random linear survey.

Truth: for a linear least-squares problem ``min |A x - b|^2`` over nodes and
cameras, the node estimates given a camera step and the node marginal
covariances are the dense formulas (solve with cameras fixed; the node blocks
of ``(A^T A)^-1``). The store must reproduce them from per-node QR conditionals.
"""

import numpy as np
import pytest

from fgloc.solve.node_conditionals import MarginalizedNodes


def _random_survey(rng: np.random.Generator, n_nodes: int, n_cams: int):
    """Per node: rows touching the node (2 cols) and some cameras (6 cols each)."""
    c6 = 6 * n_cams
    blocks = []
    for _ in range(n_nodes):
        seen = rng.choice(n_cams, size=rng.integers(1, n_cams + 1), replace=False)
        rows = 2 * len(seen)
        a_node = rng.normal(size=(rows, 2))
        a_cam = np.zeros((rows, c6))
        for r, cam in enumerate(seen):
            a_cam[2 * r : 2 * r + 2, 6 * cam : 6 * cam + 6] = rng.normal(size=(2, 6))
        blocks.append((a_node, a_cam, rng.normal(size=rows)))
    camera_prior = np.eye(c6) * 3.0  # stands in for the gauge and other nodes: makes A^T A definite
    return blocks, camera_prior


def _store(blocks, n_cams: int, theta: np.ndarray) -> MarginalizedNodes:
    store = MarginalizedNodes(n_cams)
    batch = store.new_batch({})
    for j, (a_node, a_cam, b) in enumerate(blocks):
        q, r = np.linalg.qr(np.column_stack([a_node, a_cam, b]))[0:2]
        store.add(batch, f"n{j}", theta[j], r[:2, :2], r[:2, 2:-1], r[:2, -1])
    return store


def test_positions_and_covariances_match_dense_solution() -> None:
    rng = np.random.default_rng(7)
    n_nodes, n_cams = 15, 3
    blocks, camera_prior = _random_survey(rng, n_nodes, n_cams)
    theta = rng.normal(size=(n_nodes, 2))
    store = _store(blocks, n_cams, theta)
    c6 = 6 * n_cams

    # Dense system: unknowns [all node steps, camera step].
    dim = 2 * n_nodes + c6
    rows = []
    rhs = []
    for j, (a_node, a_cam, b) in enumerate(blocks):
        a = np.zeros((len(b), dim))
        a[:, 2 * j : 2 * j + 2] = a_node
        a[:, 2 * n_nodes :] = a_cam
        rows.append(a)
        rhs.append(b)
    prior = np.zeros((c6, dim))
    prior[:, 2 * n_nodes :] = np.linalg.cholesky(camera_prior).T
    a_full = np.vstack(rows + [prior])
    info = a_full.T @ a_full
    cov_full = np.linalg.inv(info)

    # Positions for a given camera step: each node's least squares with cameras fixed.
    dc = rng.normal(size=c6)
    expected = np.array(
        [theta[j] + np.linalg.lstsq(a_node, b - a_cam @ dc, rcond=None)[0] for j, (a_node, a_cam, b) in enumerate(blocks)]
    )
    assert store.node_ids() == [f"n{j}" for j in range(n_nodes)]
    np.testing.assert_allclose(store.positions(dc[None, :]), expected, rtol=1e-10, atol=1e-10)

    # Covariances from the cameras' joint marginal.
    sigma_c = cov_full[2 * n_nodes :, 2 * n_nodes :]
    covs = store.covariances(sigma_c)
    for j in range(n_nodes):
        np.testing.assert_allclose(covs[j], cov_full[2 * j : 2 * j + 2, 2 * j : 2 * j + 2], rtol=1e-9, atol=1e-12)


def test_pop_returns_the_conditional_and_removes_the_node() -> None:
    rng = np.random.default_rng(3)
    blocks, _ = _random_survey(rng, 4, 2)
    theta = rng.normal(size=(4, 2))
    store = _store(blocks, 2, theta)
    batch, th, r, s, d = store.pop("n1")
    assert batch == 0 and "n1" not in store and len(store) == 3
    np.testing.assert_allclose(th, theta[1])
    # The popped conditional still explains node 1's rows: R^T R = A_n^T A_n.
    np.testing.assert_allclose(r.T @ r, blocks[1][0].T @ blocks[1][0], rtol=1e-10)
    assert store.node_ids() == ["n0", "n2", "n3"]
    assert store.positions(np.zeros((1, 12))).shape == (3, 2)


def test_wrong_shape_is_refused() -> None:
    store = MarginalizedNodes(2)
    batch = store.new_batch({})
    with pytest.raises(ValueError, match="shape"):
        store.add(batch, "n0", np.zeros(2), np.eye(2), np.zeros((2, 6)), np.zeros(2))
