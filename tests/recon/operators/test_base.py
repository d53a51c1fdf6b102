"""The operator contract's generic pieces: adjoint, composition, scaling, dense matrices."""

import numpy as np
import pytest

from recon.operators import MatrixOperator, ScaledOperator, dot_test, standard_cassi


def _matrix_op(rng, m=7, n=5):
    return MatrixOperator(rng.standard_normal((m, n)))


def test_adjoint_operator_swaps_forward_and_adjoint():
    rng = np.random.default_rng(0)
    op = _matrix_op(rng)
    x, y = rng.standard_normal(5), rng.standard_normal(7)
    np.testing.assert_allclose(op.H.forward(y), op.adjoint(y))
    np.testing.assert_allclose(op.H.adjoint(x), op.forward(x))
    assert dot_test(op.H, rng) < 1e-12


def test_composition_is_the_matrix_product():
    rng = np.random.default_rng(1)
    a, b = _matrix_op(rng, 4, 7), _matrix_op(rng, 7, 5)
    ab = a @ b
    x = rng.standard_normal(5)
    np.testing.assert_allclose(ab.forward(x), a.matrix @ (b.matrix @ x))
    assert dot_test(ab, rng) < 1e-12
    with pytest.raises(ValueError):
        b @ a @ a


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_scaled_operator(dtype):
    rng = np.random.default_rng(2)
    op = standard_cassi((rng.random((6, 9)) < 0.5).astype(np.float32), step=1, n_bands=4)
    s = 0.37
    sop = ScaledOperator(op, s)
    x = rng.standard_normal(op.ishape).astype(dtype)
    y = rng.standard_normal(op.oshape).astype(dtype)
    fx, ay = sop.forward(x), sop.adjoint(y)
    assert fx.dtype == dtype and ay.dtype == dtype
    np.testing.assert_allclose(fx, s * op.forward(x), rtol=1e-6)
    np.testing.assert_allclose(ay, s * op.adjoint(y), rtol=1e-6)
    np.testing.assert_allclose(sop.row_norms_sq(), s * s * np.asarray(op.row_norms_sq()), rtol=1e-6)
    assert dot_test(sop, rng) < 1e-6


def test_default_row_norms_probe_matches_the_dense_diagonal():
    rng = np.random.default_rng(3)
    op = _matrix_op(rng)
    dense = np.diag(op.matrix @ op.matrix.T)
    from recon.operators.base import LinearOperator

    np.testing.assert_allclose(LinearOperator.row_norms_sq(op), dense)


def test_shape_mismatch_is_refused():
    op = _matrix_op(np.random.default_rng(4))
    with pytest.raises(ValueError):
        op.forward(np.zeros(4))
    with pytest.raises(ValueError):
        op.adjoint(np.zeros(5))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_scaled_operator_adjoint_add_folds_the_scales(dtype):
    from recon.operators import CalibratedCassi

    rng = np.random.default_rng(5)
    op = CalibratedCassi(rng.random((2, 3, 7, 12)).astype(np.float32),
                         rng.uniform(0, 3, (2, 3)), cube_shape=(3, 7, 9))
    sop = ScaledOperator(op, 0.37)
    y = rng.standard_normal(op.oshape).astype(dtype)
    base = rng.standard_normal(op.ishape).astype(dtype)
    want = base.astype(np.float64) - 0.5 * 0.37 * op.adjoint(y).astype(np.float64)
    got = sop.adjoint_add(y, base, -0.5)
    assert got.dtype == dtype
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    out = base.copy()
    assert sop.adjoint_add(y, out, -0.5, out=out) is out
    np.testing.assert_allclose(out, want, rtol=1e-5, atol=1e-5)
    # Base weights pass through to the inner operator's gradient step.
    q = np.array([0.25, 1.0, 0.6])
    got = sop.adjoint_add(y, base, -0.5, base_weights=q)
    np.testing.assert_allclose(got, want + (q[:, None, None] - 1.0) * base, rtol=1e-5,
                               atol=1e-5)


def test_generic_adjoint_add_weighs_the_base():
    rng = np.random.default_rng(6)
    op = MatrixOperator(rng.standard_normal((5, 12)), ishape=(3, 4), oshape=(5,))
    y = rng.standard_normal(5)
    base = rng.standard_normal((3, 4))
    q = np.array([0.5, 2.0, 0.0])
    out = base.copy()
    got = op.adjoint_add(y, out, 0.3, out=out, base_weights=q)
    assert got is out
    np.testing.assert_allclose(got, q[:, None] * base + 0.3 * op.adjoint(y), rtol=1e-12)
    with pytest.raises(ValueError, match="one weight per slice"):
        op.adjoint_add(y, base, 0.3, base_weights=[1.0, 2.0])
