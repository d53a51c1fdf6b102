"""Metrics: known values on constructed cases, invariances, and agreement with skimage."""

import numpy as np
import pytest

from recon import metrics
from recon.errors import InputError

WL = np.linspace(450.0, 700.0, 16)


@pytest.fixture
def cubes():
    rng = np.random.default_rng(0)
    truth = rng.random((24, 20, 16)).astype(np.float32)
    est = truth + 0.05 * rng.standard_normal(truth.shape).astype(np.float32)
    return est, truth


def test_psnr_identical_is_inf(cubes):
    _, t = cubes
    assert metrics.psnr(t, t) == np.inf
    assert metrics.psnr_bandwise(t, t) == np.inf


def test_psnr_known_value_and_scaling():
    truth = np.zeros((8, 8, 4))
    truth[0, 0, 0] = 2.0  # max 2: both cubes are divided by 2
    est = truth + 0.2  # error 0.1 everywhere after scaling -> MSE 0.01 -> 20 dB
    assert metrics.psnr(est, truth) == pytest.approx(20.0, abs=1e-9)
    # Scaling both cubes together leaves the global PSNR unchanged.
    assert metrics.psnr(3 * est, 3 * truth) == pytest.approx(20.0, abs=1e-9)
    assert metrics.rmse(est, truth) == pytest.approx(0.2)
    assert -20 * np.log10(metrics.rmse(est, truth, scale=True)) == pytest.approx(20.0)


def test_psnr_bandwise_known_value():
    # Band l spans [l, l + 10]; an error of 1 is 0.1 of every band's range -> 20 dB in each band.
    rng = np.random.default_rng(1)
    truth = np.empty((10, 10, 3))
    for l in range(3):
        b = rng.random((10, 10))
        truth[:, :, l] = l + 10 * (b - b.min()) / (b.max() - b.min())
    est = truth + 1.0
    mean, bands = metrics.psnr_bandwise(est, truth, return_bands=True)
    np.testing.assert_allclose(bands, 20.0, atol=1e-9)
    assert mean == pytest.approx(20.0)
    # 'each' normalises the estimate by its own range: an offset is then invisible.
    assert metrics.psnr_bandwise(est, truth, normalise="each") > 200  # exact up to rounding


def test_psnr_bandwise_differs_from_global_when_bands_differ_in_scale():
    rng = np.random.default_rng(2)
    truth = rng.random((16, 16, 2))
    truth[:, :, 1] *= 0.01  # a dim band: tiny in the global PSNR, full weight band-wise
    est = truth + 0.001 * rng.standard_normal(truth.shape)
    assert metrics.psnr_bandwise(est, truth) < metrics.psnr(est, truth) - 10


def test_ssim_matches_skimage(cubes):
    from skimage.metrics import structural_similarity

    est, truth = cubes
    mean, bands = metrics.ssim(est, truth, return_bands=True)
    s = truth.max()
    for l in (0, 7, 15):
        ref = structural_similarity(truth[:, :, l] / s, est[:, :, l] / s, data_range=1.0,
                                    gaussian_weights=True, sigma=1.5, use_sample_covariance=False)
        assert bands[l] == pytest.approx(ref, abs=1e-6)
    assert mean == pytest.approx(np.mean(bands))
    assert metrics.ssim(truth, truth) == pytest.approx(1.0)
    assert mean < 0.99


def test_ssim_too_small_raises():
    a = np.ones((8, 8, 2))
    with pytest.raises(InputError):
        metrics.ssim(a, a)


def test_sam_scaled_spectra_is_zero_and_orthogonal_is_90(cubes):
    t = cubes[1].astype(np.float64)
    assert metrics.sam(t * 3.7, t) == pytest.approx(0.0, abs=1e-9)
    a = np.zeros((2, 2, 3))
    b = np.zeros((2, 2, 3))
    a[..., 0] = 1
    b[..., 1] = 2
    assert metrics.sam(a, b) == pytest.approx(90.0)
    c = a.copy()
    c[..., 1] = 1  # 45 degrees from a
    assert metrics.sam(c, a) == pytest.approx(45.0)


def test_sam_zero_spectra_are_left_out():
    t = np.ones((2, 2, 4))
    e = np.ones((2, 2, 4))
    e[0, 0] = 0  # no angle defined here
    e[1, 1, 0] = 2  # a real error elsewhere
    mean, amap = metrics.sam(e, t, return_map=True)
    assert np.isnan(amap[0, 0])
    assert np.isfinite(mean) and mean == pytest.approx(np.nanmean(amap))
    assert np.isnan(metrics.sam(np.zeros((2, 2, 3)), np.zeros((2, 2, 3))))


def test_shape_mismatch_and_nan_raise(cubes):
    est, truth = cubes
    with pytest.raises(InputError):
        metrics.psnr(est[:, :, :3], truth)
    bad = est.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError):
        metrics.psnr(bad, truth)
    with pytest.raises(InputError):
        metrics.psnr(est, np.zeros_like(truth))


def test_xyz_of_flat_unit_spectrum_has_unit_luminance():
    for wl in (WL, np.linspace(400, 700, 31)):
        xyz = metrics.cube_to_xyz(np.ones((1, 1, wl.size)), wl)
        assert xyz[0, 0, 1] == pytest.approx(1.0)


def test_srgb_of_flat_white_is_neutral():
    rgb = metrics.cube_to_srgb(np.full((4, 4, WL.size), 0.5), WL)
    assert rgb.shape == (4, 4, 3)
    assert np.ptp(rgb[0, 0]) < 0.01
    assert rgb[0, 0].min() > 0.95  # the flat image is its own exposure peak
    # Without white balance the band-limited equal-energy white is visibly not neutral.
    raw = metrics.cube_to_srgb(np.full((4, 4, WL.size), 0.5), WL, white=None)
    assert np.ptp(raw[0, 0]) > 0.05


def test_srgb_encoding_curve_is_the_standards():
    """``gamma="srgb"``: a flat cube at a quarter of the exposure peak is the neutral grey whose
    encoded value is 1.055·0.25^(1/2.4) − 0.055 (IEC 61966-2-1); linear below 0.0031308."""
    cube = np.full((2, 2, WL.size), 0.25)
    rgb = metrics.cube_to_srgb(cube, WL, peak=1.0, gamma="srgb")
    np.testing.assert_allclose(rgb, 1.055 * 0.25 ** (1 / 2.4) - 0.055, atol=2e-3)
    dark = metrics.cube_to_srgb(cube * 0.004, WL, peak=1.0, gamma="srgb")
    np.testing.assert_allclose(dark, 12.92 * 0.001, atol=1e-4)
    with pytest.raises(InputError, match="gamma"):
        metrics.cube_to_srgb(cube, WL, gamma="rec709")


def test_srgb_of_a_red_spectrum_is_red():
    cube = np.zeros((2, 2, WL.size))
    cube[..., WL > 620] = 1.0
    r, g, b = metrics.cube_to_srgb(cube, WL)[0, 0]
    assert r > 0.5 and r > 2 * g and r > 2 * b


def test_delta_e2000_identical_zero_and_changed_colour_positive(cubes):
    _, t = cubes
    mean, per_pixel = metrics.delta_e2000(t, t, WL)
    assert mean == 0.0 and per_pixel.shape == t.shape[:2]
    changed = t.copy()
    changed[:8, :8, WL < 520] *= 0.2  # make a corner yellower
    mean2, pp2 = metrics.delta_e2000(changed, t, WL)
    assert mean2 > 0
    assert pp2[:8, :8].min() > 1.0  # a visible difference there
    assert np.all(pp2[12:, 12:] == 0)


def test_wavelengths_outside_cmfs_raise():
    with pytest.raises(InputError):
        metrics.cube_to_xyz(np.ones((1, 1, 3)), [900.0, 950.0, 1000.0])


def test_all_metrics_keys(cubes):
    est, truth = cubes
    m = metrics.all_metrics(est, truth, WL)
    assert set(m) == {"psnr", "psnr_bandwise", "ssim", "sam_deg", "rmse", "delta_e2000"}
    assert all(np.isfinite(v) for v in m.values())
    assert "delta_e2000" not in metrics.all_metrics(est, truth)


@pytest.mark.parametrize("layout", ["band-major", "C"])
def test_lean_metrics_are_the_plain_expressions_to_the_bit(layout):
    """psnr, psnr_bandwise, rmse, sam and ssim work in float64 a block of rows (or a band) at a
    time, without float64 copies of the cubes (memory at the end of a `paper` solve): the same
    numbers, to the bit, as the plain NumPy expressions on the float64 cubes, on a band-major
    view (as ``recon.app`` hands them over) and a C-ordered cube, zero spectra included and
    more rows than one block."""
    from recon import metrics

    rng = np.random.default_rng(7)
    h, w, n = metrics._ROWS * 2 + 5, 17, 6
    truth = np.moveaxis(rng.random((n, h, w), dtype=np.float32), 0, 2)
    if layout == "C":
        truth = np.ascontiguousarray(truth)
    est = (truth + np.float32(0.05) * rng.standard_normal(truth.shape, dtype=np.float32))
    est[3, 4] = 0.0
    e, t = est.astype(np.float64), truth.astype(np.float64)
    s = t.max()
    assert metrics.psnr(est, truth) == float(10 * np.log10(1 / np.mean(((e - t) / s) ** 2)))
    assert metrics.rmse(est, truth) == float(np.sqrt(np.mean((e - t) ** 2)))
    assert metrics.rmse(est, truth, scale=True) == float(np.sqrt(np.mean(((e - t) / s) ** 2)))
    lo = t.min(axis=(0, 1))
    rg = t.max(axis=(0, 1)) - lo
    mse = np.mean(((e - lo) / rg - (t - lo) / rg) ** 2, axis=(0, 1))
    assert metrics.psnr_bandwise(est, truth) == float(np.mean(10 * np.log10(1 / mse)))
    elo = e.min(axis=(0, 1))
    erg = e.max(axis=(0, 1)) - elo
    mse = np.mean(((e - elo) / erg - (t - lo) / rg) ** 2, axis=(0, 1))
    assert metrics.psnr_bandwise(est, truth, normalise="each") == \
        float(np.mean(10 * np.log10(1 / mse)))
    ne, nt = np.sqrt(np.einsum("ijk,ijk->ij", e, e)), np.sqrt(np.einsum("ijk,ijk->ij", t, t))
    valid = (ne > 0) & (nt > 0)
    chord = np.linalg.norm(e[valid] / ne[valid][:, None] - t[valid] / nt[valid][:, None],
                           axis=-1)
    ang = np.full(ne.shape, np.nan)
    ang[valid] = np.degrees(2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0)))
    mean, got = metrics.sam(est, truth, return_map=True)
    np.testing.assert_array_equal(got, ang)
    assert mean == float(np.mean(ang[valid])) and np.isnan(got[3, 4])
    from skimage.metrics import structural_similarity

    ref = np.mean([structural_similarity((t / s)[:, :, l], (e / s)[:, :, l], data_range=1.0,
                                         gaussian_weights=True, sigma=1.5,
                                         use_sample_covariance=False) for l in range(n)])
    assert metrics.ssim(est, truth) == float(ref)
    # float64 inputs are the callers' arrays: never divided in place.
    e0, t0 = e.copy(), t.copy()
    assert metrics.ssim(e, t) == float(ref)
    np.testing.assert_array_equal(e, e0)
    np.testing.assert_array_equal(t, t0)
