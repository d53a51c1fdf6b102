"""The direct PSF correlation (:mod:`recon.kernels.blur`) against the FFT reference of
:func:`recon.operators.blur.convolve_views`, and the blurred operator's adjoint through it."""

import numpy as np
import pytest

from kernel_checks import RTOL32, rel
from recon import kernels
from recon.calibration import airy_kernel
from recon.operators import CalibratedCassi, dot_test
from recon.operators.blur import BlurredOperator, check_kernel, convolve_views

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


def _fft(y, k):
    with kernels.numpy_only():
        return convolve_views(y, k)


@pytest.mark.parametrize("shape,m", [((3, 17, 23), 5), ((1, 9, 9), 1), ((2, 1, 30), 3),
                                     ((2, 40, 33), 9), ((1, 4, 3), 7)])
def test_matches_the_fft_reference(shape, m):
    # An asymmetric kernel, so that a mirrored (correlation instead of convolution) or
    # shifted result would fail; a kernel wider than the view too (every tap past an edge).
    rng = np.random.default_rng(m + shape[1])
    y = rng.standard_normal(shape).astype(np.float32)
    k = check_kernel(rng.random((m, m)))
    got = convolve_views(y, k)
    assert got.dtype == np.float32 and got.shape == shape
    assert rel(got, _fft(y, k)) < RTOL32


def test_scale_and_mirror():
    from recon.kernels.blur import correlate_views

    rng = np.random.default_rng(3)
    y = rng.random((2, 12, 14)).astype(np.float32)
    k = check_kernel(rng.random((5, 5)))
    out = np.empty_like(y)
    with kernels.threads():
        correlate_views(y, np.ascontiguousarray(k[::-1, ::-1]), np.float32(-2.5), out)
    assert rel(out, -2.5 * _fft(y, k)) < RTOL32


def test_blurred_operator_dot_test_through_the_kernels():
    rng = np.random.default_rng(4)
    masks = rng.random((2, 3, 20, 27)).astype(np.float32)
    op = BlurredOperator(CalibratedCassi(masks, rng.uniform(0, 3, (2, 3)),
                                         cube_shape=(3, 20, 24)), airy_kernel(1.7))
    x = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    lhs = float(np.vdot(op.forward(x).astype(np.float64), y))
    rhs = float(np.vdot(x, op.adjoint(y).astype(np.float64)))
    assert abs(lhs - rhs) <= 1e-5 * max(abs(lhs), abs(rhs))
    assert dot_test(op) < 1e-10     # float64: the FFT reference
    with kernels.numpy_only():
        fwd, adj = op.forward(x), op.adjoint(y)
    assert rel(op.forward(x), fwd) < RTOL32
    assert rel(op.adjoint(y), adj) < RTOL32


def test_grouped_taps_give_the_one_tap_sums_to_the_bit():
    # correlate_row adds a kernel row's taps four to a pass where all four lie inside the
    # row; every column must add the same products in the same order as one tap a pass (the
    # kernel it replaced, compiled here with the same settings), edges and narrow rows
    # included.
    from recon.kernels import jit
    from recon.kernels.blur import correlate_row

    @jit()
    def by_tap(a, k, i, acc):
        h, w = a.shape
        m = k.shape[0]
        n = m // 2
        acc[:] = 0
        for p in range(m):
            ii = i + p - n
            if 0 <= ii < h:
                for q in range(m):
                    for j in range(w):
                        if 0 <= j + q - n < w:
                            acc[j] += k[p, q] * a[ii, j + q - n]

    rng = np.random.default_rng(30)
    for m in (1, 3, 5, 7, 9, 11):
        k = rng.random((m, m)).astype(np.float32)
        for h, w in ((1, 1), (3, 2), (12, 5), (9, 11), (6, 40)):
            a = rng.standard_normal((h, w)).astype(np.float32)
            got, want = np.empty(w, np.float32), np.empty(w, np.float32)
            for i in range(h):
                correlate_row(a, k, i, got)
                by_tap(a, k, i, want)
                assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), (m, h, w, i)
