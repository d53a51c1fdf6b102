"""MaskModulation: y_l = M * x_l, checked against an explicit diagonal matrix."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from recon.errors import InputError
from recon.operators import MaskModulation, dot_test

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True, database=None)


@SETTINGS
@given(l=st.integers(1, 4), h=st.integers(1, 6), w=st.integers(1, 6), seed=st.integers(0, 2**16))
def test_matches_dense_diagonal(l, h, w, seed):
    rng = np.random.default_rng(seed)
    mask = rng.random((h, w))
    op = MaskModulation(mask, l)
    dense = np.diag(np.tile(mask.astype(np.float32).astype(np.float64).ravel(), l))
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    np.testing.assert_allclose(op.forward(x).ravel(), dense @ x.ravel(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(op.adjoint(y).ravel(), dense.T @ y.ravel(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(op.row_norms_sq().ravel(), np.sum(dense**2, axis=1), rtol=1e-12)
    assert dot_test(op, rng) < 1e-6


def test_float32_in_float32_out():
    op = MaskModulation(np.ones((3, 4)), 2)
    assert op.forward(np.ones((2, 3, 4), dtype=np.float32)).dtype == np.float32
    assert op.forward(np.ones((2, 3, 4), dtype=np.float16)).dtype == np.float32
    assert op.forward(np.ones((2, 3, 4))).dtype == np.float64


@pytest.mark.parametrize("mask, n", [
    (np.ones(4), 2),                         # not 2-D
    (np.array([[1.0, np.nan]]), 2),          # non-finite
    (np.array([[1.0, np.inf]]), 2),
    (np.array([[-np.inf, 1.0]]), 2),
    (np.array([[np.nan, -np.inf], [np.inf, 0.0]]), 2),
    (np.ones((2, 2)), 0),                    # no bands
    (np.zeros((0, 3)), 1),                   # empty
])
def test_bad_input(mask, n):
    with pytest.raises(InputError):
        MaskModulation(mask, n)
