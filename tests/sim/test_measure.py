"""sim.measure: profile analysis (exact cases) and measured vs predicted geometry/dispersion."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import InputError

#: A reduced ``small`` design (300×240 sensor of 40 µm pixels, 6 bands): views of 78 px, renders
#: four times cheaper than ``small`` with the same optics.
REDUCED = dict(sensor_width_px=300, sensor_height_px=240, sensor_pixel_um=40.0,
               mask_pitch_um=80.0, band_step_nm=50.0)


def _design(**extra):
    from sim.optics.design import get_design

    return get_design("small", {**REDUCED, **extra})


# ---------------------------------------------------------------------- pure profile analysis
@pytest.mark.parametrize("x0", [10.0, 10.25, 31.6, 47.9])
@pytest.mark.parametrize("width", [1.0, 2.0])
def test_centroid_of_a_pixel_integrated_box_is_exact(x0, width):
    # A box of whole-pixel width at [x0, x0 + width) integrated over pixels [k, k + 1): the
    # pixel-centre-weighted centroid is x0 + width/2 exactly (module coordinates).
    edges = np.arange(65, dtype=np.float64)
    lo, hi = x0, x0 + width
    cover = np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0, None)
    from sim.measure import centroid

    got = centroid(cover * 7.0 + 3.0, 0, 64, background=3.0)
    assert got == pytest.approx(x0 + width / 2, abs=1e-9)


def test_peak_centroids_find_two_lines_left_to_right():
    from sim.measure import peak_centroids

    rng = np.random.default_rng(1)
    x = np.arange(120) + 0.5
    prof = (100 * np.exp(-0.5 * ((x - 30.3) / 0.7) ** 2) + 80 * np.exp(-0.5 * ((x - 91.8) / 0.7) ** 2)
            + 5 + rng.normal(0, 0.2, x.size))
    got = peak_centroids(prof, 2)
    assert len(got) == 2
    assert got[0] == pytest.approx(30.3, abs=0.05) and got[1] == pytest.approx(91.8, abs=0.05)
    # A flat, noisy profile has no peaks.
    assert peak_centroids(5 + rng.normal(0, 0.2, 100), 2) == []


def test_lit_runs_edges_are_subpixel_half_crossings():
    from sim.measure import lit_runs

    p = np.zeros(50)
    p[10:20] = 1.0
    p[9] = 0.25   # the edge at 0.5 lies a third of the way from pixel 9 to 10 (centres 9.5, 10.5)
    p[30:] = 1.0  # a run touching the end
    runs = lit_runs(p, 0.5)
    assert len(runs) == 2
    assert runs[0][0] == pytest.approx(9.5 + 1 / 3)
    assert runs[0][1] == pytest.approx(19.5 + 0.5)
    assert runs[1] == (pytest.approx(29.5 + 0.5), 50.0)
    assert lit_runs(np.zeros(5), 0.5) == []


def test_airy_blur_is_non_negative_on_a_sparse_image():
    from sim.sensor import airy_blur

    img = np.zeros((64, 64), np.float32)
    img[8:-8:9, 8:-8:7] = 1e4  # away from the border, where light would leave the image
    out = airy_blur(img, 1.65)
    assert out.min() >= 0.0
    assert out.sum() == pytest.approx(img.sum(), rel=1e-3)


# ---------------------------------------------------------------------- targets and predictions
def test_open_code_mask_opens_exactly_the_code_regions():
    from sim.measure import open_code_mask

    d = _design()
    coded, opened = d.mask_pattern(), open_code_mask(d)
    assert opened.shape == coded.shape
    assert np.all(opened[coded])                      # every open code cell stays open
    assert 0.3 < coded.sum() / opened.sum() < 0.7      # the code opens about half of them
    assert not opened.all()                            # guards and field stop stay closed


def test_line_pair_is_symmetric_and_avoids_the_guard():
    from sim.measure import line_pair, target_cube

    d = _design()
    lp = line_pair(d)
    v, g = d.view_size_px, d.guard_px
    assert lp.cols[0] >= g and lp.cols[1] == v - 1 - lp.cols[0] and lp.cols[1] < v - g
    assert lp.rows[1] == v - 1 - lp.rows[0]
    t = target_cube(d, "vlines")
    assert t.shape == (v, v) and np.array_equal(np.flatnonzero(t.sum(0)), list(lp.cols))
    with pytest.raises(InputError):
        line_pair(_design(mask_guard_px=36))
    with pytest.raises(InputError):
        target_cube(d, "spiral")


def test_predicted_gaps_follow_the_design_geometry():
    from sim.measure import predicted

    d = _design()
    p = predicted(d)
    # Rows: a copy is v tall and the next starts a (rounded) pitch lower.
    top_to_centre = d.code_region_px(0)[0] - (d.code_region_px(3)[0] + d.view_size_px)
    assert 0 <= p["gap_y_px"] <= top_to_centre
    # Columns: the guard is chosen so that the dispersed light never reaches the neighbour.
    assert p["gap_x_px"] >= 0
    assert p["views_fit"] is True and p["view_size_px"] == pytest.approx(d.view_pitch_px)
    # Shrinking the guard below the dispersion makes the light of neighbours overlap.
    assert predicted(_design(mask_guard_px=0))["gap_x_px"] < 0


# ---------------------------------------------------------------------- renders (Mitsuba)
@pytest.fixture(scope="module")
def measured():
    pytest.importorskip("mitsuba")
    from sim.measure import measure_all

    d = _design(prism_apex_deg=45.0, relay_gap_mm=190.0)
    return d, measure_all(d, spp=4, seed=3)


@pytest.mark.mitsuba
def test_measured_view_size_and_minification_match_the_lens_equation(measured):
    d, m = measured
    g = m["geometry"]
    # 1/a + 1/b = 1/f, m = b/a; the pitch is the tube width imaged: within 1 %.
    assert g["view_size_px"] == pytest.approx(d.view_pitch_px, rel=0.01)
    assert g["view_pitch_x_px"] == pytest.approx(d.view_pitch_px, rel=0.01)
    assert g["view_pitch_y_px"] == pytest.approx(d.view_pitch_px, rel=0.01)
    assert g["minification"] == pytest.approx(d.minification, rel=0.01)
    assert max(abs(x) for x in g["view_centre_err_px"]) < 1.0


@pytest.mark.mitsuba
def test_measured_dispersion_matches_sellmeier_within_half_a_pixel(measured):
    d, m = measured
    di = m["dispersion"]
    assert di["span_pred_px"] == pytest.approx(d.dispersion_span_px)
    assert abs(di["span_meas_px"] - di["span_pred_px"]) < 0.5
    assert di["max_phi_err_px"] < 0.5
    # φ grows with λ (longer wavelengths are deviated less and land at larger columns).
    assert np.all(np.diff(di["phi_meas_px"]) > 0)


@pytest.mark.mitsuba
def test_white_target_gaps_clipping_and_vignetting(measured):
    d, m = measured
    w, p = m["white"], m["predicted"]
    assert w["clipped_views"] == []
    # Measured gaps: mask cells are 2 px and the edges blur, so agree to a couple of pixels.
    assert abs(w["gap_x_px"] - p["gap_x_px"]) < 3.0
    assert abs(w["gap_y_px"] - p["gap_y_px"]) < 3.0
    thr = w["throughput_rel"]
    assert thr["0"] == pytest.approx(1.0)
    # One mirror bounce (Al, ~0.9) for the neighbours, two for the corners.
    assert all(0.6 < thr[str(v)] < 0.98 for v in (1, 2, 3, 4))
    assert all(thr[str(v)] < min(thr[str(u)] for u in (1, 2, 3, 4)) for v in (5, 6, 7, 8))
