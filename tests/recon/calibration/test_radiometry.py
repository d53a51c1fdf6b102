"""Per-band gains from synthetic ColorChecker patches: recovered within 1 %."""

import numpy as np
import pytest

from recon.calibration.radiometry import apply_gains, fit_gains, flat_field_gains, patch_spectra
from recon.errors import InputError


def _patches(rng, n_bands=26):
    lam = np.linspace(450, 700, n_bands)
    # 24 smooth, positive reflectance-like spectra times a smooth illuminant.
    centres = rng.uniform(430, 720, 24)
    widths = rng.uniform(40, 150, 24)
    refl = 0.05 + 0.9 * np.exp(-0.5 * ((lam[None] - centres[:, None]) / widths[:, None]) ** 2)
    illum = 1.0 + 0.5 * (lam - 450) / 250
    return lam, refl * illum


def test_gains_recovered_within_one_percent():
    rng = np.random.default_rng(0)
    lam, radiance = _patches(rng)
    true_c = 2.0 + np.sin(lam / 40.0)                 # (q e)^-1, varies over bands
    recon = radiance / true_c * (1 + 0.01 * rng.standard_normal(radiance.shape))
    c = fit_gains(recon, radiance)
    assert np.abs(c / true_c - 1).max() < 0.01
    # Exact data give the exact gains, and weights do not change that.
    np.testing.assert_allclose(fit_gains(radiance / true_c, radiance, weights=rng.random(24)),
                               true_c, rtol=1e-12)


def test_patch_spectra_and_apply_gains():
    rng = np.random.default_rng(1)
    lam, radiance = _patches(rng, n_bands=8)
    cube = np.zeros((4 * 12, 6 * 12, 8), dtype=np.float32)
    boxes = []
    for p in range(24):
        y0, x0 = (p // 6) * 12, (p % 6) * 12
        cube[y0:y0 + 12, x0:x0 + 12] = radiance[p]
        boxes.append((y0, x0, 12, 12))
    # Blur the patch borders: trimming keeps the means exact.
    cube[:, ::12] = 0.0
    spectra = patch_spectra(cube, boxes, trim=0.2)
    np.testing.assert_allclose(spectra, radiance, rtol=1e-6)
    g = np.linspace(1, 2, 8)
    np.testing.assert_allclose(apply_gains(cube, g), cube * g.astype(np.float32), rtol=1e-6)


def test_bad_inputs():
    with pytest.raises(InputError, match="must both be"):
        fit_gains(np.ones((24, 5)), np.ones((24, 6)))
    with pytest.raises(InputError, match=r"bands \[1\]"):
        f = np.ones((24, 3))
        f[:, 1] = 0
        fit_gains(f, np.ones((24, 3)))
    with pytest.raises(InputError, match="weights"):
        fit_gains(np.ones((24, 3)), np.ones((24, 3)), weights=-np.ones(24))
    with pytest.raises(InputError, match="finite"):
        fit_gains(np.full((24, 3), np.nan), np.ones((24, 3)))
    with pytest.raises(InputError, match="outside"):
        patch_spectra(np.ones((10, 10, 3)), [(5, 5, 10, 10)])
    with pytest.raises(InputError, match="one value per band"):
        apply_gains(np.ones((4, 4, 3)), np.ones(2))


def _whites(rng, k=2, n=3, h=30, w=32):
    """(K, L, h, w) whites: a binary mask under a smooth vignetting, per band its own level."""
    mask = (rng.random((k, 1, h, w)) > 0.5).astype(np.float64)
    vign = 1.0 - 0.2 * np.linspace(-1, 1, w)[None, None, None, :] ** 2
    level = np.array([900.0, 1500.0, 1200.0])[:n]
    return mask * vign * level[None, :, None, None], level


def test_flat_field_gains_of_the_whites_themselves_are_the_level_gains():
    """A model that is the whites over their level: the gains are exposure / level."""
    rng = np.random.default_rng(0)
    whites, level = _whites(rng)
    expo = np.array([2.0, 0.5, 1.25])
    got = flat_field_gains(lambda l: whites[:, l] / level[l], whites, expo)
    np.testing.assert_allclose(got, expo / level, rtol=1e-12)


def test_flat_field_gains_undo_a_model_too_dark_by_a_factor():
    """A model a factor a_l too dark (a blurred white's level taken for its deconvolution's):
    its gains are a_l times the level's, so the model over them matches the white again."""
    rng = np.random.default_rng(1)
    whites, level = _whites(rng)
    expo = np.ones(3)
    a = np.array([0.94, 0.95, 0.96])
    got = flat_field_gains(lambda l: a[l] * whites[:, l] / level[l], whites, expo)
    np.testing.assert_allclose(got, a * expo / level, rtol=1e-12)
    # Light the model never predicts at the crops' edges does not count: only the inside.
    edged = whites.copy()
    edged[:, :, :, :3] += 5000.0
    np.testing.assert_allclose(flat_field_gains(lambda l: whites[:, l] / level[l], edged, expo,
                                                margin=4), expo / level, rtol=1e-12)


@pytest.mark.parametrize("shape, expo", [((2, 3, 30), np.ones(3)), ((2, 3, 30, 32), np.ones(2)),
                                         ((2, 3, 30, 32), -np.ones(3)),
                                         ((2, 3, 12, 32), np.ones(3))])
def test_flat_field_gains_refuse_bad_input(shape, expo):
    with pytest.raises(InputError):
        flat_field_gains(lambda l: np.ones((2, 30, 32)), np.ones(shape), expo, margin=6)


def test_flat_field_gains_refuse_a_dark_band():
    whites = np.ones((1, 2, 30, 30))
    whites[:, 1] = 0.0
    with pytest.raises(InputError, match="band 1"):
        flat_field_gains(lambda l: np.ones((1, 30, 30)), whites, np.ones(2))
