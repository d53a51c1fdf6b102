"""The Richardson–Lucy kernels (:mod:`recon.kernels.deconvolve`) against
``skimage.restoration.richardson_lucy``, through :func:`recon.calibration.mask.deconvolve`
(its reference path inside ``kernels.numpy_only()``); the TV deconvolution's element-wise
passes against the NumPy expressions they replace, bit for bit."""

import numpy as np
import pytest

from recon import kernels
from recon.calibration.mask import airy_kernel, deconvolve
from recon.kernels import deconvolve as kdec

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


def _blurred_mask(rng, shape, radius):
    """A blurred random binary mask with noise: what a white capture's view crop looks like."""
    from scipy.signal import convolve

    m = (rng.random(shape) > 0.5).astype(np.float64)
    m = convolve(m, airy_kernel(radius), mode="same") * 1000.0
    return np.maximum(m + rng.normal(0.0, 3.0, shape), 0.0)


@pytest.mark.parametrize("shape", [(13, 17), (1, 9), (9, 1), (30, 24)])
@pytest.mark.parametrize("radius", [0.8, 1.6, 2.6])
def test_one_pass_pair_is_skimages_iteration(shape, radius):
    # One iteration of both passes against skimage's num_iter=1 on the same (unpadded) image.
    from skimage.restoration import richardson_lucy

    rng = np.random.default_rng(3)
    d = rng.random(shape).astype(np.float32) + 0.1
    k = airy_kernel(radius).astype(np.float32)
    u = np.full(shape, 0.5, np.float32)
    r = np.empty_like(u)
    kdec.ratio(u, d, np.ascontiguousarray(k[::-1, ::-1]), np.float32(1e-12), r)
    kdec.update(u, r, k)
    ref = richardson_lucy(d.astype(np.float64), k.astype(np.float64), num_iter=1, clip=False)
    np.testing.assert_allclose(u, ref, rtol=2e-6, atol=1e-7)


def test_asymmetric_psf_uses_the_mirror_where_skimage_does():
    # The Airy kernel is symmetric; a lopsided one tells the convolution from the correlation.
    from skimage.restoration import richardson_lucy

    from recon.calibration.mask import _richardson_lucy

    rng = np.random.default_rng(4)
    d = rng.random((11, 14)) + 0.1
    k = rng.random((5, 5))
    k /= k.sum()
    ref = richardson_lucy(d, k, num_iter=4, clip=False)
    np.testing.assert_allclose(_richardson_lucy(d, k, 4), ref, rtol=2e-5)


@pytest.mark.parametrize("iterations", [1, 5, 30])
def test_deconvolve_matches_skimage(iterations):
    rng = np.random.default_rng(5)
    radii = np.array([1.2, 2.4])
    views = np.stack([np.stack([_blurred_mask(rng, (21, 26), r) for r in radii])
                      for _ in range(2)])
    views[1, 0] = 0.0                                   # a dark crop stays dark
    fast = deconvolve(views, radii, iterations)
    with kernels.numpy_only():
        ref = deconvolve(views, radii, iterations)
    assert fast.dtype == ref.dtype == np.float32
    assert np.all(fast[1, 0] == 0)
    # float32 against skimage's float64: RL's multiplicative updates compound the roundings
    # a little with the iterations.
    np.testing.assert_allclose(fast, ref, rtol=1e-4 * iterations ** 0.5, atol=1e-3)


def test_deconvolve_in_place():
    rng = np.random.default_rng(6)
    radii = np.array([1.5])
    views = _blurred_mask(rng, (17, 19), 1.5)[None, None].astype(np.float32)
    want = deconvolve(views, radii, 3)
    got = deconvolve(views, radii, 3, out=views)
    assert got is views
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("n", [1, 7, (1 << 14) + 3, 50_000])
def test_tv_step_passes_are_numpys_expressions_to_the_bit(n):
    # The TV deconvolution's element-wise passes (recon.calibration.mask._fista_tv_deconvolve)
    # against the NumPy expressions they replace, bit for bit: signed zeros, zeros in the
    # spectrum and in the power, negative values, sizes around a task's block.
    rng = np.random.default_rng(n)
    spec = (rng.standard_normal(n) + 1j * rng.standard_normal(n)).astype(np.complex64)
    spec[::5] = 0.0
    spec.imag[1::7] = -0.0
    power = rng.random(n).astype(np.float32)
    power[::3] = 0.0
    kd = (rng.standard_normal(n) + 1j * rng.standard_normal(n)).astype(np.complex64)
    kd[::4] = 0.0
    want = spec.copy()
    want *= power
    want -= kd
    got = spec.copy()
    kdec.residual_spectrum(got.view(np.float32), power, kd.view(np.float32))
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))

    z, r, u, nxt = (rng.standard_normal(n).astype(np.float32) for _ in range(4))
    s, c = np.float32(1.0 / 977.0), np.float32(0.71)
    rs = r.copy()
    rs *= s
    out = np.empty_like(z)
    kdec.residual(z, r, s, out)
    assert np.array_equal(out.view(np.uint32), (z - rs).view(np.uint32))
    want = np.subtract(nxt, u)
    want *= c
    want += nxt
    kdec.momentum(nxt, u, c, out)
    assert np.array_equal(out.view(np.uint32), want.view(np.uint32))
