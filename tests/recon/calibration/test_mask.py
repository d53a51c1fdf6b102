"""Mask images from synthetic monochromatic white captures; Airy kernel and deconvolution."""

import numpy as np
import pytest
from scipy.signal import fftconvolve

from recon.calibration.mask import airy_kernel, airy_radius_px, mask_images
from recon.errors import InputError

HV, WV = 40, 56
OFFS = np.array([0, 3, 5, 8])                 # integer dispersion per band
WM = WV + OFFS.max()
THROUGHPUT = np.array([1.0, 0.85, 0.8])       # per view (mirror losses)
LEVEL = np.array([300.0, 900.0, 1500.0, 700.0])   # per band (source × QE)


def _truth(rng):
    """C[k, l]: each view's 2×2-cell mask shifted by the band's offset, times its throughput."""
    c = np.zeros((len(THROUGHPUT), len(OFFS), HV, WM))
    for k, t in enumerate(THROUGHPUT):
        cells = rng.random((HV // 2, WV // 2)) < 0.5
        m = np.kron(cells, np.ones((2, 2)))
        for l, o in enumerate(OFFS):
            c[k, l, :, o:o + WV] = t * m
    return c


def _captures(c, rng, noise=0.005, blur=None):
    boxes = np.array([(4, 3 + k * (WM + 6), HV, WM) for k in range(c.shape[0])])
    shape = (HV + 8, 3 + c.shape[0] * (WM + 6))
    caps = np.zeros((c.shape[1], *shape))
    for k, (y0, x0, h, w) in enumerate(boxes):
        caps[:, y0:y0 + h, x0:x0 + w] = LEVEL[:, None, None] * c[k]
    if blur is not None:
        psf = airy_kernel(blur)
        caps = np.stack([fftconvolve(f, psf, mode="same") for f in caps])
    caps += noise * LEVEL[:, None, None] * rng.standard_normal(caps.shape)
    return caps.astype(np.float32), boxes


def test_mask_images_recovered_and_normalised():
    rng = np.random.default_rng(0)
    c = _truth(rng)
    caps, boxes = _captures(c, rng)
    est = mask_images(caps, boxes)
    assert est.shape == c.shape and est.dtype == np.float32
    assert est.min() >= 0.0 and est.max() <= 1.0
    # One white level for all views: the relative throughput of the views survives.
    err = np.abs(est - c)
    assert err.max() < 0.05 and err.mean() < 0.01
    # Repeats are averaged: the error drops.
    reps = np.stack([_captures(c, np.random.default_rng(s))[0] for s in range(8)], axis=1)
    assert np.abs(mask_images(reps, boxes) - c).mean() < 0.6 * err.mean()


def test_dark_frame_subtracted():
    rng = np.random.default_rng(1)
    c = _truth(rng)
    caps, boxes = _captures(c, rng)
    dark = np.full(caps.shape[1:], 64.0, dtype=np.float32)
    np.testing.assert_allclose(mask_images(caps + dark, boxes, dark=dark),
                               mask_images(caps, boxes), atol=1e-4)


def test_richardson_lucy_undoes_airy_blur():
    rng = np.random.default_rng(2)
    c = _truth(rng)
    r = 1.65                                           # the paper's Airy radius in px
    caps, boxes = _captures(c, rng, noise=0.002, blur=r)
    blurred = mask_images(caps, boxes)
    sharp = mask_images(caps, boxes, airy_radius=np.full(len(OFFS), r), rl_iterations=30,
                        deconvolution="richardson-lucy")
    inner = (slice(None), slice(None), slice(3, -3), slice(3, -3))
    e_blur = np.abs(blurred - c)[inner].mean()
    e_sharp = np.abs(sharp - c)[inner].mean()
    assert e_sharp < 0.7 * e_blur, (e_blur, e_sharp)


def _blurred_whites(r, noise):
    """Captures of the synthetic masks blurred by an Airy disc of radius ``r`` px with relative
    ``noise``: (captures, boxes, radii, mean absolute error of an estimate away from the
    boxes' edges)."""
    rng = np.random.default_rng(2)
    c = _truth(rng)
    caps, boxes = _captures(c, rng, noise=noise, blur=r)
    inner = (slice(None), slice(None), slice(3, -3), slice(3, -3))

    def error(est):
        return np.abs(est - c)[inner].mean()

    return caps, boxes, np.full(len(OFFS), r), error


@pytest.mark.parametrize("shape", [(37, 50), (3, 40, 63), (2, 3, 96, 128), (2, 250, 261)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_inverse_rfft2_is_scipys_to_the_bit(shape, dtype):
    import scipy.fft as sfft

    from recon.calibration.mask import inverse_rfft2

    x = np.random.default_rng(8).standard_normal(shape).astype(dtype)
    spec = sfft.rfft2(x)
    h, w = shape[-2:]
    got = inverse_rfft2(spec, (h, w), 2)
    want = sfft.irfft2(spec, s=(h, w))
    assert got.dtype == want.dtype == dtype
    assert np.array_equal(got.view(np.uint8), want.view(np.uint8))


def test_tv_deconvolution_kernels_give_the_numpy_steps_bits(monkeypatch):
    # The FISTA steps' element-wise passes as threaded kernels against the NumPy expressions,
    # the TV prox the same in both: the same mask images to the bit.
    import recon.calibration.mask as mask
    from recon import kernels

    if not kernels.enabled():
        pytest.skip("Numba kernels switched off")
    rng = np.random.default_rng(6)
    caps, _ = _captures(_truth(rng), rng, noise=0.01, blur=1.65)
    views = np.ascontiguousarray(caps[None, :, 4:4 + HV, 3:3 + WM])
    radii = np.full(len(OFFS), 1.65)
    fused = mask.tv_deconvolve(views.copy(), radii, iterations=6)

    class Unfused:
        """recon.kernels for the deconvolution, but no fused passes."""

        def __getattr__(self, name):
            return getattr(kernels, name)

        @staticmethod
        def usable(*arrays):
            return False

    monkeypatch.setattr(mask, "kernels", Unfused())
    plain = mask.tv_deconvolve(views.copy(), radii, iterations=6)
    assert np.array_equal(fused.view(np.uint32), plain.view(np.uint32))
    assert not np.array_equal(fused, mask.tv_deconvolve(views.copy(), radii, iterations=5))


@pytest.mark.parametrize("r", [1.65, 2.1])      # the paper's mean and reddest Airy radii, px
def test_wiener_filter_undoes_airy_blur_where_richardson_lucy_stalls(r):
    # The TV deconvolution's start: one filter pass leaves less than half the error that 30
    # Richardson-Lucy iterations leave (0.027 against 0.062 at 1.65 px, 0.073 against 0.119
    # at 2.1 px when written), and far less than the blurred captures (0.16, 0.20).
    caps, boxes, radii, error = _blurred_whites(r, noise=0.002)
    e_blur = error(mask_images(caps, boxes))
    e_rl = error(mask_images(caps, boxes, airy_radius=radii, deconvolution="richardson-lucy"))
    wiener = mask_images(caps, boxes, airy_radius=radii, deconvolution="wiener")
    assert wiener.min() >= 0.0 and wiener.max() <= 1.0
    assert error(wiener) < 0.65 * e_rl < 0.65 * e_blur, (e_blur, e_rl, error(wiener))
    # Its balance trades noise for sharpness: far too much gives the blur back.
    smooth = mask_images(caps, boxes, airy_radius=radii, deconvolution="wiener", balance=10.0)
    assert error(smooth) > 2 * error(wiener)


def test_wiener_filter_inverts_a_noise_free_blur():
    # With a vanishing balance the filter is the inverse of the (circular) blur: a periodic
    # image blurred by FFT comes back to round-off away from the reflected edges.
    from recon.calibration.mask import wiener_deconvolve

    rng = np.random.default_rng(4)
    n, r = 64, 1.65
    truth = np.kron(rng.random((n // 4, n // 4)) < 0.5, np.ones((4, 4))).astype(np.float64)
    k = airy_kernel(r, support=3.0)
    blurred = fftconvolve(np.pad(truth, n, mode="wrap"), k, mode="same")[n:2 * n, n:2 * n]
    est = wiener_deconvolve(blurred[None, None].astype(np.float32), [r], balance=1e-9)[0, 0]
    inner = (slice(12, -12), slice(12, -12))
    assert np.abs(est - truth)[inner].max() < 0.02
    assert np.abs(blurred - truth)[inner].max() > 0.3


def test_tv_deconvolution_starts_from_the_wiener_filter():
    # No FISTA step: the Wiener filter's result, on a padded domain of a fast FFT length (the
    # edges' reflection differs a little from the filter's own padding, the interior not).
    from recon.calibration.mask import tv_deconvolve, wiener_deconvolve

    rng = np.random.default_rng(5)
    c = _truth(rng)
    caps, boxes = _captures(c, rng, noise=0.01, blur=1.65)
    views = caps[None, :, 4:4 + HV, 3:3 + WM]
    radii = np.full(len(OFFS), 1.65)
    start = tv_deconvolve(views.copy(), radii, iterations=0)
    wiener = wiener_deconvolve(views.copy(), radii)
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))
    scale = float(np.abs(wiener).max())
    np.testing.assert_allclose(start[inner] / scale, wiener[inner] / scale, atol=1e-4)
    # A dark crop stays dark, and the result is float32 like the crops.
    views[0, 1] = 0.0
    out = tv_deconvolve(views, radii, iterations=4)
    assert out.dtype == np.float32 and not out[0, 1].any()


@pytest.mark.parametrize("r", [1.65, 2.1])      # the paper's mean and reddest Airy radii, px
def test_tv_deconvolution_beats_the_wiener_filter_on_noisy_whites(r):
    # Flat cells with sharp edges: the TV term takes the noise off the cells without the
    # ringing and smoothing the filter leaves at their edges.  With 1 % capture noise (about
    # what four averaged paper captures carry) and the default weight the error was 0.75 of the
    # filter's when written (0.031 against 0.041 at 1.65 px, 0.061 against 0.080 at 2.1 px).
    caps, boxes, radii, error = _blurred_whites(r, noise=0.01)
    wiener = mask_images(caps, boxes, airy_radius=radii, deconvolution="wiener")
    tv = mask_images(caps, boxes, airy_radius=radii, deconvolution="tv")
    assert tv.min() >= 0.0 and tv.max() <= 1.0
    assert error(tv) < 0.8 * error(wiener), (error(wiener), error(tv))
    # Its weight trades noise for the cells' contrast: far too much flattens them.
    flat = mask_images(caps, boxes, airy_radius=radii, deconvolution="tv", tv_weight=0.1)
    assert error(flat) > 2 * error(tv)


def test_tv_deconvolution_refuses_bad_settings():
    from recon.calibration.mask import tv_deconvolve

    views = np.ones((1, 2, 16, 16), np.float32)
    for bad in (0.0, -1e-3, np.nan):
        with pytest.raises(InputError, match="TV weight must be positive"):
            tv_deconvolve(views, [1.0, 1.0], weight=bad)
    with pytest.raises(InputError, match="iterations"):
        tv_deconvolve(views, [1.0, 1.0], iterations=-1)
    with pytest.raises(InputError, match="balance"):
        tv_deconvolve(views, [1.0, 1.0], balance=0.0)


def test_airy_kernel():
    r = 3
    k = airy_kernel(r, support=3.0, oversample=9)
    assert k.shape[0] == k.shape[1] and k.shape[0] % 2 == 1
    assert abs(k.sum() - 1.0) < 1e-12
    np.testing.assert_allclose(k, k.T, atol=1e-15)
    c = k.shape[0] // 2
    # The first dark ring at R: far below the peak and below the secondary maximum beyond it.
    ring = k[c, c + r]
    assert ring < 0.05 * k[c, c]
    assert ring < k[c, c + 4]           # secondary maximum at 1.34 R
    # R = 1.22 λ N / pixel: 550 nm at f/9 on 3.69 µm pixels is ~1.64 px (the paper's 1.65).
    assert abs(airy_radius_px(550.0, 9.0, 3.69) - 1.22 * 0.55 * 9 / 3.69) < 1e-12
    with pytest.raises(InputError):
        airy_kernel(0.0)
    with pytest.raises(InputError):
        airy_radius_px(550.0, -1.0, 3.69)


def test_bad_inputs():
    rng = np.random.default_rng(3)
    c = _truth(rng)
    caps, boxes = _captures(c, rng)
    with pytest.raises(InputError, match="one size"):
        mask_images(caps, [[0, 0, 10, 10], [0, 20, 10, 11]])
    with pytest.raises(InputError, match="do not fit"):
        mask_images(caps, [[0, 0, 1000, 10]])
    with pytest.raises(InputError, match="dark"):
        mask_images(np.zeros_like(caps), boxes)
    with pytest.raises(InputError, match="positive"):
        mask_images(caps, boxes, airy_radius=-1.0)
    with pytest.raises(InputError, match="dark frame shape"):
        mask_images(caps, boxes, dark=np.zeros((3, 3)))
    with pytest.raises(InputError, match="unknown deconvolution"):
        mask_images(caps, boxes, airy_radius=1.0, deconvolution="blind")
    for bad in (0.0, -1e-3, np.nan):
        with pytest.raises(InputError, match="balance must be positive"):
            mask_images(caps, boxes, airy_radius=1.0, balance=bad)


def test_view_masks_recovered_jointly_from_smeared_whites():
    # Whites rendered as the instrument does: mask first, then each band's multi-tap smear;
    # band levels differ and are unknown.  The joint least squares recovers M_k and levels.
    from recon.calibration.mask import view_masks
    from recon.operators.smeared import smear_matrix, taps_from_positions

    rng = np.random.default_rng(5)
    k_, n_bands, hv, wv = 2, 4, 24, 30
    cells = rng.random((k_, hv // 2, wv // 2)) < 0.5
    m = np.stack([np.kron(c, np.ones((2, 2))) for c in cells]) * np.array([1.0, 0.8])[:, None, None]
    lo = np.array([0.3, 2.0, 4.6, 6.0])
    pos = lo[None, :, None] + np.linspace(0, 2.6, 40)[None, None, :] * np.ones((k_, 1, 1))
    start, weights = taps_from_positions(pos)
    wm = wv + int(start.max()) + weights.shape[2]
    level = np.array([500.0, 900.0, 1200.0, 700.0])
    boxes = np.array([(2, 2 + k * (wm + 4), hv, wm) for k in range(k_)])
    caps = np.zeros((n_bands, hv + 4, 2 + k_ * (wm + 4)))
    for k, (y0, x0, h, w) in enumerate(boxes):
        for l in range(n_bands):
            d = smear_matrix(start[k, l], weights[k, l], wv, wm)
            caps[l, y0:y0 + h, x0:x0 + w] = level[l] * m[k] @ d.T
    caps += 2.0 * rng.standard_normal(caps.shape)
    est, levels = view_masks(caps, boxes, start, weights, wv)
    assert est.shape == (k_, hv, wv) and est.dtype == np.float32
    assert est.min() >= 0.0 and est.max() <= 1.0
    assert np.abs(est - m).max() < 0.05 and np.abs(est - m).mean() < 0.01
    # The common scale is the percentile convention's (open level at the 99th percentile, noise
    # included); the relative band levels are exact.
    ratio = levels / level
    assert abs(ratio.mean() - 1) < 0.03 and np.ptp(ratio) / ratio.mean() < 0.005
    # The per-band percentile alone (mask_images) misjudges the bands whose smear is wider than
    # a mask cell: the joint fit does not.
    from recon.calibration.mask import view_stack, white_levels
    naive = white_levels(np.maximum(view_stack(caps, boxes), 0)) / level
    assert np.ptp(ratio) < 0.2 * np.ptp(naive)
    with pytest.raises(InputError):
        view_masks(caps, boxes, start, weights, wm)          # kernels do not fit
    with pytest.raises(InputError):
        view_masks(caps, boxes, start[:, :2], weights, wv)


def test_view_stack_is_float32_and_the_deconvolution_shows_progress(capsys):
    # float32 crops (a float64 stack of five paper views is 0.9 GB); the deconvolution's bar
    # counts the crops on stderr and changes nothing.
    from recon.calibration.mask import view_stack

    rng = np.random.default_rng(3)
    c = _truth(rng)
    caps, boxes = _captures(c, rng, noise=0.002, blur=1.2)
    assert view_stack(caps, boxes).dtype == np.float32
    radii = np.full(len(OFFS), 1.2)
    for how in ("tv", "wiener", "richardson-lucy"):
        quiet = mask_images(caps, boxes, airy_radius=radii, rl_iterations=3, deconvolution=how)
        capsys.readouterr()
        shown = mask_images(caps, boxes, airy_radius=radii, rl_iterations=3, progress=True,
                            deconvolution=how)
        assert "deconvolution" in capsys.readouterr().err
        np.testing.assert_array_equal(shown, quiet)


def test_mask_images_from_crops_taken_first_are_the_same():
    """The calibration crops the whites once and makes its mask images from a copy of the crops
    (``deconvolve_views``, in place), without the full frames: the same bits as
    ``mask_images`` on the frames, for every deconvolution."""
    from recon.calibration.mask import deconvolve_views, normalise_mask_images, view_stack

    rng = np.random.default_rng(5)
    caps, boxes = _captures(_truth(rng), rng)
    radii = np.full(caps.shape[0], 1.3)
    for how in ("tv", "wiener", "richardson-lucy"):
        crops = view_stack(caps, boxes)
        kept = crops.copy()
        got = normalise_mask_images(deconvolve_views(crops, radii, rl_iterations=3,
                                                     deconvolution=how))
        assert got is crops                              # in place
        np.testing.assert_array_equal(got, mask_images(caps, boxes, airy_radius=radii,
                                                       rl_iterations=3, deconvolution=how))
        assert not np.array_equal(kept, crops)
    with pytest.raises(InputError, match=r"\(K, L, h, w\) float32"):
        deconvolve_views(view_stack(caps, boxes).astype(np.float64), radii)
    with pytest.raises(InputError, match="unknown deconvolution"):
        deconvolve_views(view_stack(caps, boxes), radii, deconvolution="blind")
