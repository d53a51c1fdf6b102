"""View images that start where each view's light does (recon.calibration.extent)."""

import dataclasses

import numpy as np
import pytest

from recon.calibration import apply_homography, build_calibration, extend_views, view_leads
from recon.errors import InputError

K, L, HV, WM = 3, 4, 12, 40
PHI = np.array([0.0, 2.0, 3.5, 5.0])


def _masks(rng, starts):
    """Random 0/1 mask images, lit in view k and band l from box column ``starts[k, l]``."""
    c = (rng.random((K, L, HV, WM)) > 0.5).astype(np.float32)
    for k in range(K):
        for l in range(L):
            c[k, l, :, :starts[k, l]] = 0.0
    return c


def _cal(masks):
    hb = np.stack([np.eye(3)] + [np.array([[-1, 0, WM - 1.0], [0, 1, 0.5], [0, 0, 1]])] * 2)
    phi = np.stack([PHI] * K)
    return build_calibration(
        view_ids=(0, 1, 2), view_boxes=[(0, 40, HV, WM), (0, 0, HV, WM), (0, 80, HV, WM)],
        box_homographies=hb, mask_images=masks, wavelengths=[450.0, 500.0, 550.0, 600.0],
        dispersion=phi, checker_dispersion=phi[:, 2])


def test_leads_measure_light_before_the_offsets():
    rng = np.random.default_rng(0)
    # The centre's light begins at its offsets; view 1's 4 columns before (cut at the box's
    # first column in band 0); view 2's 2 columns after.
    starts = np.stack([np.ceil(PHI), np.maximum(np.ceil(PHI) - 4, 0), np.ceil(PHI) + 2])
    leads = view_leads(_masks(rng, starts.astype(int)), np.stack([PHI] * K))
    np.testing.assert_allclose(leads, [0.0, 4.0, -2.0])


def test_extend_views_keeps_every_box_column_and_widens_the_views():
    rng = np.random.default_rng(1)
    starts = np.stack([np.ceil(PHI), np.maximum(np.ceil(PHI) - 4, 0), np.ceil(PHI)])
    cal = _cal(_masks(rng, starts.astype(int)))
    ext = extend_views(cal)
    np.testing.assert_allclose(ext.offsets, cal.offsets - 4)
    assert ext.view_shape == (HV, cal.view_shape[1] + 4)
    assert ext.cube_shape[1] >= cal.cube_shape[1] + 4
    np.testing.assert_allclose(ext.homographies[0], np.eye(3), atol=1e-12)
    # Grid point p lands, in every view and band, on the same box column as before: the grid
    # and the view images moved together.
    p = np.array([[3.0, 5.0], [20.0, 9.0]])
    for k in range(K):
        before = apply_homography(cal.homographies[k], p)[:, 0, None] + cal.offsets[k]
        after = apply_homography(ext.homographies[k], p + [4, 0])[:, 0, None] + ext.offsets[k]
        np.testing.assert_allclose(after, before, atol=1e-9)
    # The columns before the old view column 0 of view 1 are now on the grid: its first lit
    # column in band 3 lands on view column >= 0.
    assert starts[1, 3] - ext.offsets[1, 3] >= 0


def test_no_lead_leaves_the_calibration_alone():
    rng = np.random.default_rng(2)
    starts = np.stack([np.ceil(PHI)] * K).astype(int)
    cal = _cal(_masks(rng, starts))
    assert extend_views(cal) is cal


def test_refuses_the_smeared_kernels():
    rng = np.random.default_rng(3)
    starts = np.stack([np.ceil(PHI), np.maximum(np.ceil(PHI) - 4, 0), np.ceil(PHI)])
    cal = _cal(_masks(rng, starts.astype(int)))
    with_taps = dataclasses.replace(cal, tap_start=np.zeros((K, L)),
                                    tap_weights=np.ones((K, L, 1)))
    with pytest.raises(InputError, match="smeared"):
        extend_views(with_taps)
    with pytest.raises(InputError, match="offsets"):
        view_leads(cal.mask_images, cal.offsets[:, :2])
