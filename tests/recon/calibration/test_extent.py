"""View images that start where each view's light does (recon.calibration.extent)."""

import dataclasses

import numpy as np
import pytest

from calibrations import HV, PHI, WM, K, L, three_view_calibration as _cal
from recon.calibration import (apply_homography, lead_columns, load_calibration, measure_leads,
                               operator_from_calibration, save_calibration, with_leads)
from recon.calibration.extent import led_view
from recon.errors import InputError
from recon.operators import CalibratedCassi, HomographyWarp


def _masks(rng, starts):
    """Random 0/1 mask images, lit in view k and band l from box column ``starts[k, l]``."""
    c = (rng.random((K, L, HV, WM)) > 0.5).astype(np.float32)
    for k in range(K):
        for l in range(L):
            c[k, l, :, :starts[k, l]] = 0.0
    return c


# The centre's light begins at its offsets; view 1's 4 columns before (cut at the box's first
# column in band 0); view 2's 2 columns after.
STARTS = np.stack([np.ceil(PHI), np.maximum(np.ceil(PHI) - 4, 0), np.ceil(PHI) + 2]).astype(int)


def test_leads_measure_light_before_the_offsets():
    rng = np.random.default_rng(0)
    leads = measure_leads(_masks(rng, STARTS), np.stack([PHI] * K))
    np.testing.assert_allclose(leads, [0.0, 4.0, -2.0])
    with pytest.raises(InputError, match="offsets"):
        measure_leads(_masks(rng, STARTS), np.stack([PHI] * K)[:, :2])


def test_lead_columns_are_whole_non_negative_and_zero_for_the_centre():
    rng = np.random.default_rng(1)
    starts = STARTS.copy()
    starts[0] -= 2                      # even a centre that leads keeps the grid: 0
    cal = _cal(_masks(rng, starts))
    assert lead_columns(cal).tolist() == [0, 4, 0]
    assert with_leads(cal).view_leads.dtype == np.int64


def test_led_view_keeps_every_box_column():
    # Cube point p lands on the same box column whether view column 0 sits at the offsets or
    # E columns before them.
    h = np.array([[-1.02, 0.01, 39.0], [0.0, 1.0, 0.5], [1e-4, 0.0, 1.0]])
    o = PHI + 0.3
    m, o2 = led_view(h, o, 4)
    p = np.array([[3.0, 5.0], [20.0, 9.0]])
    before = apply_homography(h, p)[:, :1] + o
    after = apply_homography(m, p)[:, :1] + o2
    np.testing.assert_allclose(after, before, atol=1e-9)
    assert led_view(h, o, 0)[0] is h


def test_the_shifted_model_starts_led_views_earlier(tmp_path):
    rng = np.random.default_rng(2)
    cal = with_leads(_cal(_masks(rng, STARTS)))
    op = operator_from_calibration(cal, model="shifted")
    h, w, n_bands = cal.cube_shape
    wv = cal.view_shape[1]
    m, o = led_view(cal.homographies[1], cal.offsets[1], 4)
    by_hand = CalibratedCassi(cal.mask_images,
                              np.stack([cal.offsets[0], o, cal.offsets[2]]),
                              [None, HomographyWarp(m, (h, w), (h, wv + 4)),
                               HomographyWarp(cal.homographies[2], (h, w), (h, wv))],
                              (n_bands, h, w))
    x = rng.random(op.ishape).astype(np.float32)
    np.testing.assert_array_equal(op.forward(x), by_hand.forward(x))
    # Light the led view's first box columns now receive: the model predicts some there.
    plain = operator_from_calibration(dataclasses.replace(cal, view_leads=None),
                                      model="shifted")
    first = slice(0, int(np.ceil(cal.offsets[1, -1])))
    assert op.forward(x)[1][:, first].sum() > 1.5 * plain.forward(x)[1][:, first].sum()
    # Saved and loaded with the calibration.
    save_calibration(tmp_path / "cal", cal)
    np.testing.assert_array_equal(load_calibration(tmp_path / "cal").view_leads, [0, 4, 0])


@pytest.mark.parametrize("leads", [[0, -1, 0], [0, 1.5, 0], [0, 1000, 0], [0, 1]])
def test_bad_leads(leads):
    rng = np.random.default_rng(3)
    cal = _cal(_masks(rng, STARTS))
    with pytest.raises(InputError, match="view_leads"):
        dataclasses.replace(cal, view_leads=np.array(leads))
