"""BlurredOperator: y = P * (A x), one point-spread function on every view after the model."""

import numpy as np
import pytest
from scipy.signal import convolve2d

from recon.calibration import airy_kernel
from recon.errors import InputError
from recon.operators import CalibratedCassi, MatrixOperator, dot_test
from recon.operators.blur import BlurredOperator, check_kernel, convolve_views
from recon.solvers.base import row_norms_sq


def calibrated(rng, k=2, l_=3, h=12, w=16):
    masks = rng.random((k, l_, h, w + 3)).astype(np.float32)
    offsets = rng.uniform(0.0, 3.0, size=(k, l_))
    return CalibratedCassi(masks, offsets, cube_shape=(l_, h, w))


def dense_blur(kernel, h, w):
    """The 'same'-size convolution with zero boundary as a dense (h·w, h·w) matrix."""
    cols = []
    for i in range(h * w):
        e = np.zeros(h * w)
        e[i] = 1.0
        cols.append(convolve2d(e.reshape(h, w), kernel, mode="same").ravel())
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("m", [1, 3, 5])
def test_matches_dense_reference(m):
    rng = np.random.default_rng(m)
    op = calibrated(rng)
    kernel = rng.random((m, m))
    b = BlurredOperator(op, kernel)
    k_, h, w = op.oshape
    p = dense_blur(check_kernel(kernel).astype(np.float64), h, w)
    x = rng.standard_normal(op.ishape)
    ax = op.forward(x)
    want = np.stack([(p @ ax[v].ravel()).reshape(h, w) for v in range(k_)])
    np.testing.assert_allclose(b.forward(x), want, rtol=1e-9, atol=1e-9)
    y = rng.standard_normal(op.oshape)
    py = np.stack([(p.T @ y[v].ravel()).reshape(h, w) for v in range(k_)])
    np.testing.assert_allclose(b.adjoint(y), op.adjoint(py), rtol=1e-9, atol=1e-9)


def test_dot_test_float32_and_float64():
    rng = np.random.default_rng(0)
    b = BlurredOperator(calibrated(rng), airy_kernel(1.7))
    assert dot_test(b) < 1e-10
    x = rng.random(b.ishape).astype(np.float32)
    assert b.forward(x).dtype == np.float32
    np.testing.assert_allclose(b.forward(x), b.forward(x.astype(np.float64)), rtol=1e-4,
                               atol=1e-5)


def test_a_delta_kernel_is_the_identity():
    rng = np.random.default_rng(1)
    op = calibrated(rng)
    b = BlurredOperator(op, np.ones((1, 1)))
    x = rng.random(op.ishape).astype(np.float32)
    np.testing.assert_allclose(b.forward(x), op.forward(x), rtol=1e-5, atol=1e-6)


def test_adjoint_add_is_base_plus_scaled_adjoint():
    rng = np.random.default_rng(2)
    b = BlurredOperator(calibrated(rng), airy_kernel(1.3))
    y = rng.random(b.oshape).astype(np.float32)
    base = rng.random(b.ishape).astype(np.float32)
    got = b.adjoint_add(y, base, -0.5)
    np.testing.assert_allclose(got, base - 0.5 * b.adjoint(y), rtol=1e-5, atol=1e-6)
    q = np.linspace(0.1, 1.0, b.ishape[0]).astype(np.float32)
    got = b.adjoint_add(y, base, -0.5, base_weights=q)
    np.testing.assert_allclose(got, q[:, None, None] * base - 0.5 * b.adjoint(y), rtol=1e-5,
                               atol=1e-6)


def test_blur_keeps_a_flat_measurement_away_from_the_edges():
    y = np.ones((1, 30, 30), np.float32)
    k = check_kernel(airy_kernel(2.0))
    out = convolve_views(y, k)
    np.testing.assert_allclose(out[0, 6:-6, 6:-6], 1.0, rtol=1e-5)
    # Zero outside the view: the corner keeps only the quarter of the kernel that lands inside.
    n = k.shape[0] // 2
    np.testing.assert_allclose(out[0, 0, 0], k[n:, n:].sum(), rtol=1e-5)


def test_mean_row_norm_is_the_frobenius_norm_over_the_lit_rows():
    rng = np.random.default_rng(3)
    op = calibrated(rng, k=1, l_=2, h=6, w=7)
    b = BlurredOperator(op, airy_kernel(1.2))
    a = np.stack([b.forward(e.reshape(op.ishape)).ravel()
                  for e in np.eye(int(np.prod(op.ishape)))], axis=1)
    rows = np.sum(a ** 2, axis=1)
    exact = rows[rows > 1e-12].mean()
    # Hutchinson with four Rademacher probes: an estimate, within 15 % on this tiny problem.
    assert abs(b.mean_row_norm_sq() / exact - 1.0) < 0.15


def test_gap_tv_is_refused_with_a_clear_error():
    b = BlurredOperator(calibrated(np.random.default_rng(4)), airy_kernel(1.5))
    with pytest.raises(InputError, match="row norms"):
        row_norms_sq(b)


@pytest.mark.parametrize("kernel", [np.ones((2, 2)), np.ones((3, 5)), -np.ones((3, 3)),
                                    np.zeros((3, 3)), np.full((3, 3), np.nan)])
def test_bad_kernels_are_refused(kernel):
    with pytest.raises(InputError):
        BlurredOperator(calibrated(np.random.default_rng(5)), kernel)


def test_needs_view_stacks():
    with pytest.raises(InputError, match="K, H, W"):
        BlurredOperator(MatrixOperator(np.eye(4)), np.ones((3, 3)))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_band_forward_is_the_forward_of_one_band(dtype):
    """One band's blurred model equals the blurred forward of the cube holding that image in
    that band only (to the bit in float32 through the kernels; the inner operator without a
    band_forward takes the full forward)."""
    rng = np.random.default_rng(5)
    op = BlurredOperator(calibrated(rng), airy_kernel(1.6))
    dense = BlurredOperator(MatrixOperator(rng.random((2 * 12 * 16, 3 * 12 * 16)),
                                           (3, 12, 16), (2, 12, 16)), airy_kernel(1.6))
    for o in (op, dense):
        for band in range(3):
            img = rng.random((12, 16)).astype(dtype)
            x = np.zeros((3, 12, 16), dtype)
            x[band] = img
            got, ref = o.band_forward(band, img), o.forward(x)
            assert got.dtype == ref.dtype and got.shape == ref.shape
            if dtype == np.float32 and o is op:
                assert np.array_equal(got, ref)
            else:
                np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6 * np.abs(ref).max())
