"""sim.optics.design: paper defaults, stable hash, overrides, geometry, dispersion and the mask."""

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

from recon.errors import InputError
from sim.optics.design import PRESETS, VIEW_GRID, Design, get_design, parse_overrides
from sim.optics.glass import apex_for_span

# Schott N-BK7 Sellmeier coefficients (Schott data sheet; C in µm²).
B = (1.03961212, 0.231792344, 1.01046945)
C = (0.00600069867, 0.0200179144, 103.560653)


def n_bk7(lam_nm):
    l2 = (np.asarray(lam_nm, float) / 1000.0) ** 2
    return np.sqrt(1 + sum(b * l2 / (l2 - c) for b, c in zip(B, C)))


def _refract(d, nrm, n1, n2):
    """Vector Snell's law: unit direction d through a surface with unit normal nrm (against d)."""
    cos_i = -d @ nrm
    eta = n1 / n2
    k = 1 - eta**2 * (1 - cos_i**2)
    assert k >= 0, "total internal reflection"
    return eta * d + (eta * cos_i - np.sqrt(k)) * nrm


def traced_offsets_px(apex_deg, lam_nm, center_nm, focal_mm, pixel_um):
    """Independent check: trace the chief ray through the two prism faces in 2-D with vector
    Snell's law (incidence set by minimum deviation at the centre wavelength, found numerically
    as the symmetric ray), then image the exit directions with an ideal lens."""
    A = math.radians(apex_deg)
    # faces: normals of the entrance and exit faces of a prism with apex pointing +y
    n_in = np.array([-math.cos(A / 2), math.sin(A / 2)])
    n_out = np.array([math.cos(A / 2), math.sin(A / 2)])
    # symmetric path inside the glass at centre wavelength: horizontal, so the incoming ray makes
    # θ1 with the entrance normal where sin θ1 = n sin(A/2); build the incoming direction from it
    nc = n_bk7(center_nm)
    th1 = math.asin(nc * math.sin(A / 2))
    inward = -n_in
    rot = np.array([[math.cos(th1), -math.sin(th1)], [math.sin(th1), math.cos(th1)]])
    d0 = rot @ inward  # pick the rotation sense that gives a horizontal ray inside
    if abs(_refract(d0, n_in, 1.0, nc)[1]) > 1e-9:
        d0 = rot.T @ inward
    out = []
    for lam in np.atleast_1d(lam_nm):
        n = n_bk7(lam)
        d1 = _refract(d0, n_in, 1.0, n)
        d2 = _refract(d1, -n_out, n, 1.0)
        out.append(math.atan2(d2[1], d2[0]))
    ang = np.array(out)
    d_in = _refract(_refract(d0, n_in, 1.0, nc), -n_out, nc, 1.0)
    ang_c = math.atan2(d_in[1], d_in[0])
    return np.abs(focal_mm * np.tan(ang - ang_c) / (pixel_um * 1e-3)) * np.sign(np.asarray(lam_nm) - center_nm)


def test_defaults_are_the_papers_numbers():
    d = Design()
    assert d == PRESETS["paper"]
    assert (d.mirror_length_mm, d.tube_width_mm, d.mirror_material) == (240.0, 24.0, "Al")
    assert (d.objective_focal_mm, d.objective_f_number) == (60.0, 4.0)
    assert d.relay_focal_mm == d.collimator_focal_mm == d.imaging_focal_mm == 50.0
    assert (d.mask_pitch_um, d.mask_fill) == (7.4, 0.5)
    assert (d.prism_glass, d.prism_apex_deg) == ("BK7", 17.0)
    assert (d.sensor_width_px, d.sensor_height_px, d.sensor_pixel_um, d.bit_depth) == (3376, 2704, 3.69, 12)
    assert (d.band_min_nm, d.band_max_nm, d.filter_min_nm, d.filter_max_nm) == (450.0, 700.0, 450.0, 700.0)
    assert d.diffuser_transmittance == 0.85
    assert d.views == (0, 1, 2, 3, 4) and d.kaleidoscope
    # one mask cell covers 2×2 sensor pixels (7.4 µm / 3.69 µm)
    assert abs(d.mask_cell_px - 2.0) < 0.01
    # the paper's Airy radius: ≈ 6.1 µm ≈ 1.65 px in the visible (550 nm)
    r = float(d.airy_radius_um(550.0))
    assert abs(r - 6.1) < 0.05 and abs(r / d.sensor_pixel_um - 1.65) < 0.02
    np.testing.assert_allclose(d.wavelengths, np.arange(450.0, 701.0, 10.0))


def test_hash_is_stable_across_processes():
    code = "from sim.optics.design import get_design as g; print(g('paper').hash, g('small').hash)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == [PRESETS["paper"].hash, PRESETS["small"].hash]
    assert len(PRESETS["paper"].hash) == 16 and int(PRESETS["paper"].hash, 16) >= 0
    assert Design().hash == Design.from_dict(Design().to_dict()).hash


def _changed(name, value):
    if isinstance(value, bool):
        yield not value
    elif name == "mask_guard_px":
        yield 60
    elif name == "views":
        yield (0, 1, 2)
    elif isinstance(value, str):
        yield {"mirror_material": "Ag", "prism_glass": "F2", "qe_curve": "flat"}[name]
    elif isinstance(value, int):
        yield value + 1
        yield value - 1
    else:
        for v in (value * 1.01, value * 0.99, value - 5.0, value + 0.5):
            yield v


@pytest.mark.parametrize("f", [f.name for f in dataclasses.fields(Design)])
def test_hash_changes_with_every_field(f):
    base = Design()
    for v in _changed(f, getattr(base, f)):
        try:
            other = base.replace(**{f: v})
        except InputError:
            continue
        assert other.hash != base.hash
        return
    pytest.fail(f"no valid change found for {f}")


def test_overrides_parse_to_field_types():
    d = get_design("paper", parse_overrides([
        "prism_apex_deg=20.5", "sensor_width_px=400", "kaleidoscope=false", "views=0,1", "mask_guard_px=auto",
        "prism_glass=F2",
    ]))
    assert d.prism_apex_deg == 20.5 and isinstance(d.sensor_width_px, int) and d.sensor_width_px == 400
    assert d.kaleidoscope is False and d.views == (0,)  # no kaleidoscope: the single view
    assert d.mask_guard_px is None and d.prism_glass == "F2"
    assert get_design("paper", {"views": "[0, 3, 4]", "mask_guard_px": "40"}).views == (0, 3, 4)


@pytest.mark.parametrize("override", [
    {"no_such_field": "1"}, {"prism_apex_deg": "abc"}, {"prism_apex_deg": "nan"},
    {"sensor_width_px": "1.5"}, {"kaleidoscope": "maybe"}, {"mask_pitch_um": "-1"},
    {"views": "0,9"}, {"views": "0,0"}, {"mask_fill": "1.0"}, {"prism_glass": "unobtainium"},
    {"qe_curve": "nope"}, {"band_max_nm": "800"}, {"prism_apex_deg": "90"},
])
def test_overrides_reject_bad_input(override):
    with pytest.raises(InputError):
        get_design("paper", override)


def test_parse_overrides_and_presets_reject_bad_forms():
    with pytest.raises(InputError):
        parse_overrides(["prism_apex_deg"])
    with pytest.raises(InputError):
        parse_overrides(["=3"])
    with pytest.raises(InputError):
        get_design("huge")
    with pytest.raises(InputError):
        Design.from_dict({**Design().to_dict(), "extra": 1})


def test_minification_formula_and_the_papers_grid_does_not_fit():
    d = Design()
    a, b, f = d.object_distance_mm, d.image_distance_mm, d.relay_focal_mm
    assert a == d.mirror_length_mm + d.relay_gap_mm
    assert abs(1 / a + 1 / b - 1 / f) < 1e-12
    assert abs(d.minification - b / a) < 1e-12
    # the paper as printed: a = 240 mm, m = 50/190, a 3×3 grid of 18.9 mm does not fit 9.98 mm
    raw = d.replace(relay_gap_mm=0.0)
    assert abs(raw.minification - 50.0 / 190.0) < 1e-12
    assert abs(3 * raw.view_size_mask_mm - 18.947) < 1e-3
    assert not raw.grid_fits_sensor_height and not raw.views_fit
    # the chosen gap is the smallest whole millimetre that fits
    assert d.grid_fits_sensor_height and d.views_fit
    assert not d.replace(relay_gap_mm=d.relay_gap_mm - 1).grid_fits_sensor_height


def _rects_disjoint_and_inside(d):
    rects = d.view_rects()
    H, W = d.sensor_height_px, d.sensor_width_px
    occ = np.zeros((H, W), np.int32)
    for v, (r, c, h, w) in rects.items():
        assert r >= 0 and c >= 0 and r + h <= H and c + w <= W
        occ[r:r + h, c:c + w] += 1
        lr0, lc0, lr1, lc1 = d.light_extent_px(v)
        assert c <= lc0 and lc1 <= c + w and r <= lr0 and lr1 <= r + h
    assert occ.max() == 1


@pytest.mark.parametrize("name", ["paper", "small"])
def test_views_fit_without_overlap(name):
    d = get_design(name)
    assert d.views_fit
    _rects_disjoint_and_inside(d)


def test_small_preset_is_small():
    d = get_design("small")
    assert d.sensor_width_px * d.sensor_height_px <= 640 * 512
    assert 64 <= d.view_size_px <= 300
    assert abs(d.mask_cell_px - 2.0) < 1e-9
    assert 8 <= d.n_bands <= 12
    step = np.diff(d.dispersion_px)
    assert np.all(step > 0) and 1.5 <= step.mean() <= 2.0


def test_single_view_design_uses_the_grid_area():
    d = get_design("paper", {"kaleidoscope": "false"})
    assert d.views == (0,) and list(d.view_rects()) == [0]
    assert d.views_fit
    assert abs(d.view_pitch_px - d.view_size_px) < 2.0 and d.view_size_px > 2 * get_design("paper").view_size_px


def test_bk7_17deg_dispersion_is_about_50px():
    d = Design()
    lam = np.array([450.0, 700.0])
    traced = traced_offsets_px(17.0, lam, d.prism_center_nm, 50.0, 3.69)
    span_traced = traced[1] - traced[0]
    assert abs(d.dispersion_span_px - span_traced) < 1e-6 * span_traced
    assert 45.0 < d.dispersion_span_px < 55.0  # "about 50 px" …
    assert d.dispersion_span_px < 60.0  # … short of the paper's ≥ 60 px
    phi = d.dispersion_px
    assert np.all(np.diff(phi) > 0) and abs(d.dispersion_px_at(d.prism_center_nm)) < 1e-12
    # blue is spread more than red (BK-7 dispersion is not linear in λ)
    assert np.diff(phi)[0] > 2 * np.diff(phi)[-1]


def test_the_apex_that_reaches_60px_exists_and_exceeds_17deg():
    a60 = apex_for_span("BK7", 60.0, 450.0, 700.0, 575.0, 50.0, 3.69)
    assert a60 > 17.0
    d = Design().replace(prism_apex_deg=a60)
    assert abs(d.dispersion_span_px - 60.0) < 1e-3
    traced = traced_offsets_px(a60, np.array([450.0, 700.0]), 575.0, 50.0, 3.69)
    assert abs(traced[1] - traced[0] - 60.0) < 1e-3
    assert Design().derived()["apex_for_60px_deg"] == pytest.approx(a60)


def test_guard_keeps_views_apart_and_too_small_a_guard_is_detected():
    d = Design()
    assert d.guard_px >= math.ceil(d.dispersion_span_px) and d.guard_px % 2 == 0
    assert not d.replace(mask_guard_px=10).views_fit


@pytest.mark.parametrize("name", ["paper", "small"])
def test_mask_pattern(name):
    d = get_design(name)
    m = d.mask_pattern()
    assert m.dtype == bool and m.shape == (d.mask_cells, d.mask_cells)
    assert np.array_equal(m, d.mask_pattern())
    assert not np.array_equal(m, d.replace(mask_seed=1).mask_pattern())
    r0, c0 = d.mask_origin_px
    cell = d.mask_cell_px
    centres = (np.arange(d.mask_cells) + 0.5) * cell
    rows, cols = r0 + centres, c0 + centres
    inside_any = np.zeros_like(m)
    for v in VIEW_GRID:
        r, c, h, w = d.code_region_px(v)
        ri = (rows >= r) & (rows < r + h)
        ci = (cols >= c) & (cols < c + w)
        block = m[np.ix_(ri, ci)]
        assert abs(block.mean() - d.mask_fill) < 0.05  # random code at the requested fill
        inside_any[np.ix_(ri, ci)] = True
        # the guard stripe right of the code region is chrome
        gi = (cols >= c + w) & (cols < c + h)
        assert gi.sum() >= d.guard_px / cell - 1 and not m[np.ix_(ri, gi)].any()
    assert not m[~inside_any].any()  # everything outside the code regions is chrome
