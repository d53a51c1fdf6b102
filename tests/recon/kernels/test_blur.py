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
