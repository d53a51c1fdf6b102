"""Calibration from rendered captures on the designs that used to break it: small views (78 px),
the traditional full-frame CASSI (``kaleidoscope=False``, one view) and a wide dispersion
(prism apex 50°, twice the span).  Reduced sensors and 6 bands keep each under a few seconds."""

import numpy as np
import pytest

from recon.calibration.views import overlapping_pair

pytestmark = pytest.mark.mitsuba

#: ``small`` on a 300×240 sensor of 40 µm pixels (2×2-pixel mask cells): 78 px views.
REDUCED = {"sensor_width_px": 300, "sensor_height_px": 240, "sensor_pixel_um": 40.0,
           "mask_pitch_um": 80.0, "band_step_nm": 50.0}


@pytest.fixture(scope="module", autouse=True)
def cache(fresh_cache):
    return fresh_cache


def _check(design):
    from kaleidospec.calibrate import calibrate

    cal = calibrate(design, progress=False, repeats=2)
    ids = tuple(sorted(design.views))
    assert tuple(cal.view_ids) == ids
    boxes = np.asarray(cal.view_boxes)
    hs, ws = design.sensor_height_px, design.sensor_width_px
    assert overlapping_pair(boxes) is None
    assert np.all(boxes[:, :2] >= 0)
    assert np.all(boxes[:, 0] + boxes[:, 2] <= hs) and np.all(boxes[:, 1] + boxes[:, 3] <= ws)
    # Each box holds its view's light: the design's bound at the pass band's edges, up to
    # 3 px (the outermost rows and columns get a fraction of a pixel or of a band's light,
    # and a touching neighbour shares a rim), and no more than a few pixels beyond it.
    for b, v in zip(boxes, ids):
        r0, c0, r1, c1 = design.light_extent_px(v)
        assert r0 - 4 <= b[0] <= r0 + 3 and r1 - 3 <= b[0] + b[2] <= r1 + 4, (v, b, r0, r1)
        assert c0 - 4 <= b[1] <= c0 + 3 and c1 - 3 <= b[1] + b[3] <= c1 + 4, (v, b, c0, c1)
    assert np.all(np.isfinite(cal.gains)) and np.all(cal.gains > 0)
    return cal, boxes


def test_small_views():
    from sim.optics.design import get_design

    d = get_design("small", REDUCED)
    assert d.view_size_px == 78
    _check(d)


def test_traditional_full_frame_cassi():
    from sim.optics.design import get_design

    d = get_design("small", {**REDUCED, "kaleidoscope": False, "views": (0,)})
    cal, boxes = _check(d)
    assert boxes.shape == (1, 4)
    # One view: its box is the single lit region, about the whole view (no 3×3 split).
    assert boxes[0, 2] >= d.view_size_px - 2


def test_wide_dispersion():
    from sim.optics.design import get_design

    # 98 px views: at 50° the guard stripe (22 px) still leaves room for a 4-square board.
    base = {**REDUCED, "sensor_width_px": 376, "sensor_height_px": 300, "sensor_pixel_um": 32.0,
            "mask_pitch_um": 64.0}
    d = get_design("small", {**base, "prism_apex_deg": 50.0})
    assert d.dispersion_span_px > 1.9 * get_design("small", base).dispersion_span_px
    _check(d)


def test_deconvolved_masks_get_gains_that_reproduce_the_whites():
    """A lens whose diffraction spans a pixel (f/60 on the reduced sensor: Airy radius 0.8–1.3
    px): the mask images are deconvolved and the model blurs them again.  Its gains fit the
    model of every band's white to the white itself; the white level's gains (expo / level,
    the blurred white's level) leave the model several per cent too dark everywhere."""
    from kaleidospec.calibrate import calibrate_from_captures, deconvolution_radii
    from kaleidospec.instrument import render_captures
    from recon.calibration import operator_from_calibration
    from recon.calibration.mask import view_stack, white_levels
    from sim.optics.design import get_design

    d = get_design("small", {**REDUCED, "imaging_f_number": 60.0})
    assert deconvolution_radii(d) is not None
    caps = render_captures(d, repeats=2)
    cal = calibrate_from_captures(d, captures=caps, repeats=2)
    assert cal.psf is not None
    whites = view_stack(caps.white, cal.view_boxes)
    expo = np.array([m["radiance_scale"] for m in caps.meta["white"]])
    level_gains = expo / white_levels(whites)
    op = operator_from_calibration(cal, model="shifted")
    x = np.zeros(op.ishape, np.float32)
    inner = (slice(None), slice(10, -10), slice(10, -10))
    fitted, level = [], []
    for l in range(cal.n_bands):
        x[l] = 1.0
        m = op.forward(x)[inner].astype(np.float64)
        x[l] = 0.0
        w = whites[:, l][inner] / expo[l]
        sel = m > 0.05 * m.max()
        norm = np.linalg.norm(w[sel])
        fitted.append(np.linalg.norm(m[sel] / cal.gains[l] - w[sel]) / norm)
        level.append(np.linalg.norm(m[sel] / level_gains[l] - w[sel]) / norm)
    ratio = cal.gains / level_gains
    print("rms misfit of the whites: fitted", np.round(fitted, 4), "level", np.round(level, 4),
          "gains / level gains", np.round(ratio, 4))
    # Every band's white is fitted at least as well as with the level's gains (0.86 of their
    # misfit on average here), and the fitted gains are 1-4 % lower: the blurred white's level
    # is below the deconvolved one (with the level's gains, the ratio would be 1).
    assert np.all(np.array(fitted) <= np.array(level) + 1e-12)
    assert np.mean(fitted) < 0.9 * np.mean(level)
    assert np.all((ratio > 0.9) & (ratio < 0.995))
