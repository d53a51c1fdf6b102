"""Optics of the Mitsuba model (small design): kaleidoscope mirror copies and prism dispersion."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba


@pytest.fixture(scope="module")
def design():
    from sim.optics.design import get_design

    return get_design("small")


def _open_mask(d):
    return np.ones((d.mask_cells, d.mask_cells), dtype=bool)


def _f_target(v):
    """An asymmetric "F" with soft edges: no mirror or flip maps it onto itself."""
    from scipy.ndimage import gaussian_filter

    t = np.zeros((v, v), np.float32)
    t[int(0.1 * v):int(0.25 * v), int(0.15 * v):int(0.8 * v)] = 1.0
    t[int(0.1 * v):int(0.9 * v), int(0.15 * v):int(0.3 * v)] = 1.0
    t[int(0.45 * v):int(0.58 * v), int(0.15 * v):int(0.6 * v)] = 0.6
    return gaussian_filter(t, 1.5)[:, :, None]


def _corr(a, b):
    a = a - a.mean()
    b = b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def _best_corr(img, ref, r, c, flip, search=8):
    """Highest correlation of ``ref`` with the (flipped) v×v cut of ``img`` at (r, c) over shifts
    of up to ``search`` px: the prism's distortion moves the outer views by a few pixels, which
    calibration (a homography per view) absorbs."""
    v = ref.shape[0]
    best = -1.0
    for dr in range(-search, search + 1):
        for dc in range(-search, search + 1):
            rr, cc = r + dr, c + dc
            if rr < 0 or cc < 0 or rr + v > img.shape[0] or cc + v > img.shape[1]:
                continue
            cut = img[rr:rr + v, cc:cc + v]
            if flip == "x":
                cut = cut[:, ::-1]
            elif flip == "y":
                cut = cut[::-1, :]
            best = max(best, _corr(ref, cut))
    return best


def test_kaleidoscope_row_and_column_neighbours_are_mirror_images(design):
    from sim.optics.render import render_direct

    d = design.replace(views=(0, 1, 2, 3, 4))
    v = d.view_size_px
    lam = d.prism_center_nm  # no dispersion at the centre wavelength
    img = render_direct(d, _f_target(v), [lam], spp=4, intervals=[[lam, lam]],
                        mask_pattern=_open_mask(d), progress=False,
                        windows=[(0, 0, d.sensor_height_px, d.sensor_width_px)])[0]
    r0, c0 = d.code_region_px(0)[:2]
    centre = img[r0:r0 + v, c0:c0 + v]
    # The centre view comes out upright and unflipped (cube row 0 at the top, column 0 left).
    assert _corr(centre, _f_target(v)[:, :, 0]) > 0.97
    Hs, Ws, p = d.sensor_height_px, d.sensor_width_px, d.view_pitch_px
    # A neighbour is the centre view reflected in the tube wall between them. (A corner view
    # would be reflected twice.)
    planes = {1: ("x", Ws / 2 - p / 2), 2: ("x", Ws / 2 + p / 2),
              3: ("y", Hs / 2 - p / 2), 4: ("y", Hs / 2 + p / 2)}
    for view, (axis, plane) in planes.items():
        if axis == "x":
            r, c = r0, int(round(2 * plane - (c0 + v)))
        else:
            r, c = int(round(2 * plane - (r0 + v))), c0
        assert _best_corr(img, centre, r, c, axis) > 0.95, view
        assert _best_corr(img, centre, r, c, None) < 0.6, view
        # The mirror loses a little light (Al, and some vignetting by the tube), never adds any.
        ratio = img[max(r - 8, 0):r + v + 8, max(c - 8, 0):c + v + 8].sum() / centre.sum()
        assert 0.7 < ratio < 1.0, (view, ratio)


def test_dispersion_shift_matches_sellmeier_prediction(design):
    from sim.optics.render import render_direct

    d = design.replace(views=(0,))
    v = d.view_size_px
    line = np.zeros((v, v, 1), np.float32)
    line[:, v // 2 - 1:v // 2 + 1] = 1.0
    r0 = d.code_region_px(0)[0]
    rows = slice(r0 + v // 2 - 8, r0 + v // 2 + 8)  # near the axis: no prism "smile"
    cols = np.arange(d.sensor_width_px) + 0.5
    pos = {}
    for lam in (475.0, 650.0):
        img = render_direct(d, line, [lam], spp=8, intervals=[[lam, lam]],
                            mask_pattern=_open_mask(d), progress=False)[0]
        prof = img[rows].sum(axis=0)
        pos[lam] = float((prof * cols).sum() / prof.sum())
    measured = pos[650.0] - pos[475.0]
    predicted = float(d.dispersion_px_at(650.0) - d.dispersion_px_at(475.0))
    assert abs(predicted) > 5.0  # several pixels apart, so the check means something
    assert abs(measured - predicted) < 0.5, (measured, predicted)
    # Each line sits where the design puts it: axis at the sensor centre, plus φ(λ).
    for lam in (475.0, 650.0):
        expect = d.sensor_width_px / 2 + float(d.dispersion_px_at(lam))
        assert abs(pos[lam] - expect) < 0.5, (lam, pos[lam], expect)
