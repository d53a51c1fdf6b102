"""Independent dense references for the operator tests: explicit matrices built with loops, to
compare the fast operators against."""

import math

import numpy as np


def shift_matrix(phi: float, w_in: int, w_out: int) -> np.ndarray:
    """Row-wise linear-interpolation shift: out[x] = (1-t) v[x-a] + t v[x-a-1] for the x in
    [0, w_out) (what lands outside is dropped)."""
    a = math.floor(phi)
    t = phi - a
    s = np.zeros((w_out, w_in))
    for u in range(w_in):
        for x, weight in ((u + a, 1.0 - t), (u + a + 1, t)):
            if 0 <= x < w_out and weight > 0:
                s[x, u] += weight
    return s


def flip_matrix(shape, axes) -> np.ndarray:
    """The permutation matrix of an image reversed along ``axes`` (0: rows, 1: columns)."""
    h, w = shape
    idx = np.arange(h * w).reshape(h, w)
    if 0 in axes:
        idx = idx[::-1]
    if 1 in axes:
        idx = idx[:, ::-1]
    return np.eye(h * w)[idx.ravel()]


def assert_matches_dense(op, a: np.ndarray, rng, norms_atol: float = 1e-9) -> None:
    """``op`` (float64 path) against its dense matrix ``a``: forward, adjoint and the diagonal
    of :math:`AA^\\top`, each on random inputs, then the dot test of its adjoint."""
    from recon.operators import dot_test

    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    np.testing.assert_allclose(op.forward(x).ravel(), a @ x.ravel(), atol=1e-9)
    np.testing.assert_allclose(op.adjoint(y).ravel(), a.T @ y.ravel(), atol=1e-9)
    np.testing.assert_allclose(op.row_norms_sq().ravel(), np.diag(a @ a.T), atol=norms_atol)
    assert dot_test(op, rng) < 1e-6
