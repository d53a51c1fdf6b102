"""sim.sensor: shot and read noise statistics, saturation, ADC, seeds, Airy blur, radiometry."""

import numpy as np
import pytest

from recon.errors import InputError
from sim import sensor
from sim.optics.design import get_design

SMALL = get_design("small")


def _unit_gain(**kw):
    """A 24-bit design whose conversion gain is exactly 1 e⁻/DN, so DN are electrons."""
    return SMALL.replace(bit_depth=24, full_well_e=float(2**24 - 1), **kw)


def test_shot_noise_variance_equals_mean():
    d = _unit_gain(read_noise_e=0.0)
    for mean in (30.0, 1000.0):
        dn = sensor.digitise(np.full((200, 200), mean, np.float32), d, seed=1)
        assert abs(dn.mean() - mean) < 0.02 * mean
        assert abs(dn.var() / mean - 1.0) < 0.05


def test_read_noise_adds_in_quadrature():
    d = _unit_gain(read_noise_e=20.0)
    dn = sensor.digitise(np.full((200, 200), 1000.0, np.float32), d, seed=2)
    assert abs(dn.var() / (1000.0 + 400.0) - 1.0) < 0.05


def test_saturation_clips_at_full_well_and_adc_range():
    d = SMALL
    e = np.array([[0.0, 0.5, 1e3], [d.full_well_e, 2 * d.full_well_e, 1e9]], np.float32)
    dn = sensor.digitise(e, d, seed=3)
    assert dn.dtype == np.float32
    assert dn.min() >= 0 and dn.max() <= 4095 and np.all(dn == np.round(dn))
    assert np.all(dn[1] >= 4095 - 4 * d.read_noise_e * 4095 / d.full_well_e)
    clean = sensor.digitise(e, d, noise=False)
    assert clean[1].tolist() == [4095.0, 4095.0, 4095.0] and clean[0, 0] == 0.0
    rng = np.random.default_rng(4)
    big = sensor.digitise(rng.uniform(0, 3 * d.full_well_e, (64, 64)).astype(np.float32), d, seed=5)
    assert big.min() >= 0 and big.max() == 4095


def test_same_seed_same_frame():
    e = np.random.default_rng(0).uniform(0, 5000, (32, 48)).astype(np.float32)
    a = sensor.digitise(e, SMALL, seed=7)
    b = sensor.digitise(e, SMALL, rng=np.random.default_rng(7))
    c = sensor.digitise(e, SMALL, seed=8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_airy_blur_conserves_energy_and_widens_with_wavelength():
    img = np.zeros((65, 65), np.float32)
    img[32, 32] = 1.0
    m2 = []
    for lam in (450.0, 575.0, 700.0):
        r = float(get_design("paper").airy_radius_um(lam)) / 3.69
        out = sensor.airy_blur(img, r)
        assert abs(out.sum() - 1.0) < 1e-5 and out.min() >= -1e-7
        y, x = np.mgrid[:65, :65] - 32
        m2.append(float((out * (x**2 + y**2)).sum()))
    assert m2[0] < m2[1] < m2[2]
    assert m2[2] / m2[0] > 1.5  # (700/450)² ≈ 2.4 less the pixel's own width
    k = sensor.airy_kernel(1.65)
    assert abs(k.sum() - 1.0) < 1e-6 and np.array_equal(k, k.T) and np.array_equal(k, k[::-1])
    assert k[k.shape[0] // 2, k.shape[1] // 2] == k.max()


def test_mean_electrons_radiometry():
    d = SMALL.replace(qe_curve="flat")
    wl = d.wavelengths
    e = np.full((4, 5, wl.size), 1e-3, np.float32)  # W m^-2 nm^-1
    got = sensor.mean_electrons(e, d)
    h, c = 6.62607015e-34, 2.99792458e8
    # The filter passes 450–700 nm: the end bands' boxes are cut in half (12.5 of 25 nm).
    widths = np.full(wl.size, 25.0)
    widths[[0, -1]] = 12.5
    expected = sum(1e-3 * (20e-6) ** 2 * 0.1 * dl * lam * 1e-9 / (h * c)
                   for dl, lam in zip(widths, wl))
    assert np.allclose(got, expected, rtol=1e-5)
    assert np.allclose(sensor.mean_electrons(e, d.replace(exposure_ms=200.0)), 2 * got, rtol=1e-6)
    qe = sensor.quantum_efficiency("mono_cmos", np.arange(400, 721, 5))
    assert np.all((qe > 0.2) & (qe < 0.8))
    # diffraction moves light but keeps its total (source away from the edges)
    pt = np.zeros((41, 41, wl.size), np.float32)
    pt[20, 20] = 1e-3
    blurred = sensor.mean_electrons(pt, d, diffraction=True)
    assert abs(blurred.sum() / sensor.mean_electrons(pt, d).sum() - 1.0) < 1e-5


def test_capture_auto_exposure_and_bad_input():
    rng = np.random.default_rng(0)
    cube = rng.uniform(0, 1, (16, 16, SMALL.n_bands)).astype(np.float32)
    dn = sensor.capture(cube, SMALL, auto_exposure=0.5, noise=False)
    assert abs(dn.max() - 0.5 * 4095) <= 1.0
    with pytest.raises(InputError):
        sensor.capture(cube[..., :3], SMALL)
    bad = cube.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError):
        sensor.capture(bad, SMALL)
    with pytest.raises(InputError):
        sensor.quantum_efficiency("nope", 500.0)


def test_end_bands_count_the_photons_their_filter_passes():
    """A flat white scene: the first and last bands' intervals are half as wide inside the
    450–700 nm filter, so per unit irradiance they collect half the electrons of a full band
    at the same wavelength and QE (it was twice that, the full step)."""
    from sim.bands import band_intervals, band_widths

    d = SMALL.replace(qe_curve="flat")
    iv = band_intervals(d)
    assert iv[0].tolist() == [450.0, 462.5] and iv[-1].tolist() == [687.5, 700.0]
    np.testing.assert_allclose(band_widths(d), [12.5] + [25.0] * 9 + [12.5])
    scale = sensor.electron_scale(d)
    per_nm = scale / (d.wavelengths * band_widths(d))       # QE flat: the same for every band
    np.testing.assert_allclose(per_nm, per_nm[1], rtol=1e-12)
    assert scale[0] / scale[1] == pytest.approx(0.5 * 450 / 475, rel=1e-12)


@pytest.mark.parametrize("shape", [(300, 70), (5,), (2, 3, 40)])
def test_digitise_matches_numpy_reference_to_the_bit(shape):
    """The compiled readout (blocks of rows, read noise drawn block by block) gives the frame
    of the plain NumPy model, bit for bit: zeros, counts past the full well, float64 input."""
    d = SMALL
    rng = np.random.default_rng(11)
    e = rng.uniform(0, 1.5 * d.full_well_e, shape)
    e.reshape(-1)[::7] = 0.0
    for x in (e.astype(np.float32), e):
        for seed in (0, 1):
            a = sensor.digitise(x, d, seed=seed)
            b = sensor.digitise_reference(x, d, seed=seed)
            assert a.dtype == np.float32 and a.shape == b.shape
            assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
    deep = SMALL.replace(bit_depth=24, full_well_e=float(2**26 - 1))  # past float32 integers
    big = rng.uniform(0, 1.2 * deep.full_well_e, shape)
    assert np.array_equal(sensor.digitise(big, deep, seed=2),
                          sensor.digitise_reference(big, deep, seed=2))
    quiet = d.replace(read_noise_e=0.0)
    assert np.array_equal(sensor.digitise(e, quiet, seed=3),
                          sensor.digitise_reference(e, quiet, seed=3))
    assert np.array_equal(sensor.digitise(e, d, noise=False),
                          sensor.digitise_reference(e, d, noise=False))


def test_digitise_of_a_mostly_dark_frame_matches_the_reference_to_the_bit():
    """Blocks of rows that are mostly dark draw their Poisson counts for the lit pixels only;
    the frame, and the read noise drawn after the counts from the same stream, are the
    reference's bit for bit: a line-like frame whose first rows are lit throughout (dense
    blocks) and the rest dark but for two columns (sparse ones), means below and above 10
    (NumPy's two Poisson methods), an all-dark frame."""
    d = SMALL
    rng = np.random.default_rng(12)
    e = np.zeros((700, 90))
    e[:300] = rng.uniform(0, 1.5 * d.full_well_e, (300, 90))
    e[300:, 40] = rng.uniform(0, 8, 400)
    e[300:, 41] = rng.uniform(10, 2 * d.full_well_e, 400)
    for x in (e.astype(np.float32), e, np.zeros((520, 30), np.float32)):
        for seed in (0, 4):
            a = sensor.digitise(x, d, seed=seed)
            b = sensor.digitise_reference(x, d, seed=seed)
            assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
    assert np.any(sensor.digitise(e, d, seed=0)[300:, 40] != sensor.digitise(e, d, seed=1)[300:, 40])


def test_digitise_rejects_negative_and_nan():
    for bad in (np.array([[1.0, -1.0]]), np.array([[np.nan, 1.0]])):
        with pytest.raises(InputError):
            sensor.digitise(bad, SMALL, seed=0)
