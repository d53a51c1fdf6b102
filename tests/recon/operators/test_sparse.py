"""SparseMatrixOperator: g = A f with a scipy.sparse A, its exact adjoint and row norms."""

import numpy as np
import pytest
import scipy.sparse as sp

from recon.errors import InputError
from recon.operators import SparseMatrixOperator, dot_test


def _random(seed=0, ishape=(3, 4, 5), oshape=(2, 4, 6), density=0.2):
    rng = np.random.default_rng(seed)
    a = sp.random(int(np.prod(oshape)), int(np.prod(ishape)), density=density, random_state=rng,
                  format="csr", dtype=np.float64)
    return a, SparseMatrixOperator(a, ishape, oshape), rng


def test_matches_the_dense_matrix_and_is_adjoint():
    a, op, rng = _random()
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    np.testing.assert_allclose(op.forward(x).ravel(), a.toarray() @ x.ravel(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(op.adjoint(y).ravel(), a.toarray().T @ y.ravel(), rtol=1e-5,
                               atol=1e-6)
    assert dot_test(op) < 1e-6
    np.testing.assert_allclose(op.row_norms_sq().ravel(),
                               (a.toarray().astype(np.float32) ** 2).sum(axis=1), rtol=1e-5)


def test_keeps_the_input_precision():
    _, op, rng = _random(1)
    assert op.forward(np.ones(op.ishape, np.float32)).dtype == np.float32
    assert op.adjoint(np.ones(op.oshape, np.float64)).dtype == np.float64


def test_bad_input():
    a, _, _ = _random(2)
    with pytest.raises(InputError, match="sparse"):
        SparseMatrixOperator(a.toarray(), (3, 4, 5), (2, 4, 6))
    with pytest.raises(InputError, match="needs"):
        SparseMatrixOperator(a, (3, 4, 4), (2, 4, 6))
    bad = a.copy()
    bad.data[0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        SparseMatrixOperator(bad, (3, 4, 5), (2, 4, 6))
