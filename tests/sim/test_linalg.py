"""sim.linalg: the products and the solve compute what numpy's do, in their fixed order."""

from __future__ import annotations

import numpy as np
import pytest

from sim.linalg import dot, gram, matmul, matvec, solve, tmatvec


def test_products_agree_with_numpy() -> None:
    rng = np.random.default_rng(40)
    A = rng.normal(size=(7, 5))
    B = rng.normal(size=(5, 4))
    x = rng.normal(size=5)
    y = rng.normal(size=7)
    assert dot(x, x) == pytest.approx(float(x @ x), rel=1e-14)
    np.testing.assert_allclose(matvec(A, x), A @ x, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(tmatvec(A, y), A.T @ y, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(matmul(A, B), A @ B, rtol=1e-13, atol=1e-14)
    G = gram(A)
    np.testing.assert_allclose(G, A.T @ A, rtol=1e-13, atol=1e-14)
    assert np.array_equal(G, G.T)
    # views (a transposed matrix, a row block, a strided column) as the controllers pass them
    np.testing.assert_allclose(matmul(A[:3].T, A[:3]), A[:3].T @ A[:3], rtol=1e-13, atol=1e-14)
    assert dot(A[:, 1], y) == pytest.approx(float(A[:, 1] @ y), rel=1e-13)


def test_sums_run_in_index_order() -> None:
    # 1e16 + 1 rounds back to 1e16: in index order the 1 is lost, in any other order it is not
    big = np.array([1e16, 1.0, -1e16])
    assert dot(big, np.ones(3)) == 0.0
    assert matvec(big[None, :], np.ones(3))[0] == 0.0
    assert tmatvec(big[:, None], np.ones(3))[0] == 0.0
    assert gram(np.array([[1e8], [1.0], [1e-8]]))[0, 0] == (1e16 + 1.0) + 1e-16


def test_solve_matches_numpy_on_the_controllers_systems() -> None:
    rng = np.random.default_rng(7)
    n, k = 12, 6  # a KKT matrix as the momentum QP builds it: indefinite, regularised
    J = rng.normal(size=(k, n))
    H = gram(rng.normal(size=(n + 3, n))) + 1e-4 * np.eye(n)
    K = np.block([[H, J.T], [J, -1e-7 * np.eye(k)]])
    rhs = rng.normal(size=n + k)
    x = solve(K, rhs)
    np.testing.assert_allclose(x, np.linalg.solve(K, rhs), rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(K @ x, rhs, atol=1e-9)
    K0, r0 = K.copy(), rhs.copy()
    solve(K, rhs)
    assert np.array_equal(K, K0) and np.array_equal(rhs, r0)  # inputs untouched


def test_solve_pivots_and_refuses_a_singular_matrix() -> None:
    assert solve(np.array([[0.0, 1.0], [1.0, 0.0]]), np.array([2.0, 3.0])).tolist() == [3.0, 2.0]
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.array([[1.0, 2.0], [2.0, 4.0]]), np.array([1.0, 1.0]))
