"""Dispersion phi(lambda) from synthetic masked line captures: recovered within 0.1 px."""

import numpy as np
import pytest
from scipy.special import erf

from recon.calibration.dispersion import (fit_dispersion, line_centroids, line_profiles,
                                          normalise_offsets, profile_centroids)
from recon.calibration.mask import view_stack
from recon.errors import InputError

B = (1.03961212, 0.231792344, 1.01046945)
C = (0.00600069867, 0.0200179144, 103.560653)


def bk7(lam_nm):
    l2 = (np.asarray(lam_nm, dtype=np.float64) * 1e-3) ** 2
    return np.sqrt(1 + sum(b * l2 / (l2 - c) for b, c in zip(B, C)))


def true_phi(lam_nm, span_px):
    """Shift proportional to n(λ) - n(550), scaled to ``span_px`` over 450-700 nm (+x to blue)."""
    n = bk7(lam_nm)
    return span_px * (n - bk7(550.0)) / (bk7(450.0) - bk7(700.0))


def _line_captures(rng, wavelengths, phi, x0s, hv=60, wm=90, width=1.6, noise=0.01):
    """Per band, a vertical line of ``width`` px at x0_k + phi_k(λ) in each view, rows masked."""
    n_views = len(x0s)
    boxes = np.array([(5, 5 + k * (wm + 7), hv, wm) for k in range(n_views)])
    shape = (hv + 10, 5 + n_views * (wm + 7))
    xe = np.arange(wm + 1) - 0.5                         # pixel edges
    row_mod = [np.repeat(rng.random(hv // 2) < 0.6, 2)[:, None] for _ in range(n_views)]
    caps = np.zeros((len(wavelengths), *shape))
    for l in range(len(wavelengths)):
        for k, (y0, x0, _, _) in enumerate(boxes):
            c = x0s[k] + phi[k, l]
            # Box profile of the line integrated over each pixel, then the mask's rows.
            cdf = 0.5 * (erf((xe - c + width / 2) / 0.5) - erf((xe - c - width / 2) / 0.5))
            prof = 0.5 * (cdf[:-1] + cdf[1:])
            caps[l, y0:y0 + hv, x0:x0 + wm] = 800.0 * (0.5 + l / 10) * row_mod[k] * prof
    caps += noise * 800.0 * rng.standard_normal(caps.shape)
    return caps.astype(np.float32), boxes


def test_centroids_and_fit_recover_phi():
    rng = np.random.default_rng(0)
    lam = np.arange(450.0, 701.0, 25.0)
    span = 20.0
    phi1 = true_phi(lam, span)
    # Three views with slightly different dispersion (mirror misalignment).
    phi = np.stack([phi1, 1.02 * phi1, 0.97 * phi1])
    x0s = [40.3, 50.75, 45.1]
    caps, boxes = _line_captures(rng, lam, phi, x0s)
    cen = line_centroids(caps, boxes)
    assert np.abs(cen - (np.array(x0s)[:, None] + phi)).max() < 0.1
    fit = fit_dispersion(lam, cen, ref_nm=550.0, degree=2)
    np.testing.assert_allclose(fit(lam), phi, atol=0.1)
    # Between the bands too.
    fine = np.linspace(450, 700, 51)
    truth = np.array([1.0, 1.02, 0.97])[:, None] * true_phi(fine, span)[None]
    np.testing.assert_allclose(fit(fine), truth, atol=0.1)
    np.testing.assert_allclose(fit([550.0]), 0.0, atol=1e-12)
    assert np.all(fit.rms_px < 0.1)


def test_profiles_one_capture_at_a_time_are_the_stacks():
    """The calibration takes each line capture's profiles as it is read out (the stack is never
    held): band by band they are the whole stack's to the bit, and so are the centroids; the
    profiles are the rows' float64 sums of the view crops."""
    rng = np.random.default_rng(3)
    lam = np.arange(450.0, 701.0, 25.0)
    phi = np.stack([true_phi(lam, 20.0), 1.02 * true_phi(lam, 20.0)])
    caps, boxes = _line_captures(rng, lam, phi, [40.3, 50.75])
    whole = line_profiles(caps, boxes)
    one_by_one = np.stack([line_profiles(c[None], boxes)[:, 0] for c in caps], axis=1)
    np.testing.assert_array_equal(one_by_one, whole)
    views = view_stack(caps, boxes)
    for k in range(len(boxes)):
        np.testing.assert_array_equal(whole[k], views[k].sum(axis=1, dtype=np.float64))
    np.testing.assert_array_equal(profile_centroids(one_by_one), line_centroids(caps, boxes))
    with pytest.raises(InputError, match=r"\(K, L, w\)"):
        profile_centroids(whole[0])


def test_sellmeier_is_well_fitted_in_inverse_lambda_squared():
    # Paper scale: ~50 px over 450-700 nm; a cubic in 1/λ² (the default) holds it to a few
    # hundredths of a pixel.
    lam = np.arange(450.0, 701.0, 10.0)
    phi = true_phi(lam, 50.0)[None]
    fit = fit_dispersion(lam, phi + 12.0, ref_nm=None)
    assert fit.ref_nm == lam[lam.size // 2]
    rel = phi - true_phi(fit.ref_nm, 50.0)
    assert np.abs(fit(lam) - rel).max() < 0.05


def test_normalise_offsets():
    o, m = normalise_offsets([[3.5, 1.25], [2.0, 7.0]])
    assert m == 1.25 and o.min() == 0.0
    np.testing.assert_allclose(o, [[2.25, 0.0], [0.75, 5.75]])


def test_bad_inputs():
    rng = np.random.default_rng(1)
    lam = np.array([450.0, 550.0, 650.0])
    caps, boxes = _line_captures(rng, lam, np.zeros((1, 3)), [40.0])
    caps[1] = rng.standard_normal(caps[1].shape)             # no line in band 1
    with pytest.raises(InputError, match="no line found in view box 0, band 1"):
        line_centroids(caps, boxes)
    with pytest.raises(InputError, match="do not fit"):
        line_centroids(caps, [[0, 0, 500, 10]])
    with pytest.raises(InputError, match=r"\(K, L\)"):
        fit_dispersion(lam, np.zeros((2, 4)))
    with pytest.raises(InputError, match="at least 3 bands"):
        fit_dispersion(lam[:2], np.zeros((1, 2)), degree=2)
    with pytest.raises(InputError, match="at least 4 bands"):
        fit_dispersion(lam, np.zeros((1, 3)))
    with pytest.raises(InputError, match="degree"):
        fit_dispersion(lam, np.zeros((1, 3)), degree=0)
    with pytest.raises(InputError, match="positive"):
        fit_dispersion(-lam, np.zeros((1, 3)), degree=1)


def test_phase_normalisation_keeps_each_views_subpixel_phase():
    from recon.calibration.dispersion import normalise_offsets_phase

    o, shift = normalise_offsets_phase([[3.25, 5.5], [12.75, 14.0]])
    np.testing.assert_allclose(o, [[0.25, 2.5], [0.75, 2.0]])
    np.testing.assert_array_equal(shift, [3.0, 12.0])
    assert np.all(np.mod(shift, 1) == 0) and o.min() >= 0 and np.all(o.min(axis=1) < 1)


def test_fit_positions_include_the_line_column():
    lam = np.linspace(450, 700, 6)
    phi = 40.0 / (lam / 100) ** 2
    cen = np.stack([phi + 12.3, phi + 30.0])
    fit = fit_dispersion(lam, cen, ref_nm=550.0, degree=3)
    np.testing.assert_allclose(fit.positions(lam), cen, atol=1e-6)


def test_band_mean_positions_average_the_band():
    from recon.calibration.dispersion import band_mean_positions

    lam = np.array([450.0, 500.0, 550.0, 600.0, 650.0])
    u = 1.0 / (lam * 1e-3) ** 2
    cen = np.stack([10.0 - 8.0 * (u - u[2]), 30.0 + 7.0 * (u - u[2])])     # linear in 1/λ²
    fit = fit_dispersion(lam, cen, ref_nm=550.0, degree=1)
    iv = np.stack([lam, lam + 25.0], axis=1)                 # nominal λ at the interval's edge
    # The mean of 1/λ² over [lo, hi] is 1/(lo hi): the band's light lands, on average, there.
    u_mean = 1.0 / (iv[:, 0] * iv[:, 1] * 1e-6)
    exact = np.stack([10.0 - 8.0 * (u_mean - u[2]), 30.0 + 7.0 * (u_mean - u[2])])
    got = band_mean_positions(fit, iv, samples=256)
    np.testing.assert_allclose(got, exact, atol=1e-4)
    assert np.all(np.abs(got - fit.positions(lam)) > 0.1)    # not the nominal wavelength's
