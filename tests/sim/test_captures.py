"""Calibration captures: the checkerboard target, averaging of repeats, the capture set."""

import numpy as np
import pytest

from recon.errors import InputError
from sim.captures import CHECKER_NM, capture, checker_layout, checker_target, render_captures
from sim.optics.design import get_design

OVR = {"band_step_nm": 50.0}


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


def _board_extent(cube):
    dark = cube[:, :, 0] < 0.5
    ys, xs = np.nonzero(dark)
    return ys.min(), ys.max(), xs.min(), xs.max()


@pytest.mark.parametrize("over", [
    {},                                                              # 158 px views, 20 px guard
    {"sensor_width_px": 300, "sensor_height_px": 240, "sensor_pixel_um": 40.0,
     "mask_pitch_um": 80.0},                                         # 78 px views
    {"kaleidoscope": False, "views": (0,)},                          # one 478 px view
    {"prism_apex_deg": 60.0},                                        # 48 px guard stripe
], ids=["small", "78px", "full-frame", "apex60"])
def test_checker_target_fits_every_code_region(over):
    d = get_design("small", {**OVR, **over})
    lay = checker_layout(d)
    cube, (cols, rows) = checker_target(d)
    v, g, s = d.view_size_px, d.guard_px, lay["square_px"]
    assert cube.shape == (v, v, d.n_bands) and cube.dtype == np.float32
    y0, y1, x0, x1 = _board_extent(cube)
    # The board (with its dark squares) leaves a white quiet zone on every side, inside the
    # columns every view codes (the centre codes [0, v - guard), a mirrored view [guard, v)).
    assert y0 > 0 and y1 < v - 1
    assert x0 >= g + 2 and x1 < v - g - 2
    # Squares of at least 5 mask cells, and enough of them for OpenCV (> 2 inner corners).
    assert s >= 5 * d.mask_cell_px - 1e-9
    assert (cols, rows) == (lay["squares"][0] - 1, lay["squares"][1] - 1)
    assert 3 <= cols <= 7 and 3 <= rows <= 7
    assert x1 - x0 + 1 <= (cols + 1) * s and y1 - y0 + 1 <= (rows + 1) * s


def test_checker_layout_keeps_the_small_board_and_scales_down():
    assert checker_layout(get_design("small", OVR))["pattern_size"] == (7, 7)
    sizes = [checker_layout(get_design("small", {**OVR, "sensor_width_px": w,
                                                 "sensor_height_px": h, "sensor_pixel_um": p,
                                                 "mask_pitch_um": 2 * p}))
             for w, h, p in ((600, 480, 20.0), (376, 300, 32.0), (300, 240, 40.0))]
    # Smaller views: squares shrink with the view down to 5 mask cells (10 px), then fewer.
    sq = [z["square_px"] for z in sizes]
    assert sq == sorted(sq, reverse=True) and min(sq) == 10
    n = [z["squares"][0] * z["squares"][1] for z in sizes]
    assert n == sorted(n, reverse=True) and n[0] > n[-1]


def test_checker_layout_rejects_a_guard_too_wide():
    # At 70° the guard stripe (74 px) leaves 10 px that every view codes.
    with pytest.raises(InputError, match="guard stripe"):
        checker_layout(get_design("small", {**OVR, "prism_apex_deg": 70.0}))


def test_repeats_average_the_noise():
    d = get_design("small", OVR)
    cube, _ = checker_target(d)
    wl = d.wavelengths
    a1, m1 = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=1, seed=1)
    b1, _ = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=1, seed=2)
    a4, m4 = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=4, seed=11)
    b4, _ = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=4, seed=21)
    clean, m0 = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=0)
    lit = clean > 0.2 * clean.max()
    s1 = np.std((a1 - b1)[lit])
    s4 = np.std((a4 - b4)[lit])
    assert s4 < 0.65 * s1          # 1/sqrt(4) = 0.5 in theory
    assert m4["repeats"] == 4 and m0["repeats"] == 0 and m4["design_hash"] == d.hash
    assert m4["monochromatic_nm"] == CHECKER_NM
    assert np.all(clean == np.round(clean))  # noise-free frames are still quantised DN


def test_singles_are_the_repeats_before_averaging():
    """``singles`` keeps the first repeats as read out (the photon-transfer pair): their mean
    is the two-repeat capture, and their difference is pure sensor noise."""
    d = get_design("small", OVR)
    cube, _ = checker_target(d)
    wl = d.wavelengths
    pair = np.empty((2, d.sensor_height_px, d.sensor_width_px), np.float32)
    mean, _ = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=2, seed=7, singles=pair)
    np.testing.assert_allclose(0.5 * (pair[0] + pair[1]), mean, atol=1e-3)
    assert np.all(pair == np.round(pair)) and not np.array_equal(pair[0], pair[1])
    one, _ = capture(d, cube, wl, wavelength_nm=CHECKER_NM, repeats=1, seed=7)
    np.testing.assert_array_equal(pair[0], one)     # the same draw as a one-repeat capture


def test_render_captures_is_complete_and_tagged():
    from sim.transport import exact as transport

    d = get_design("small", OVR)
    before = set(transport._MEMO)
    caps = render_captures(d, repeats=1)
    assert caps.noise_frames is None            # one repeat: no pair of single frames
    L = d.n_bands
    hs, ws = d.sensor_height_px, d.sensor_width_px
    assert caps.white.shape == caps.line.shape == (L, hs, ws)
    assert caps.checker.shape == caps.checker_white.shape == caps.colorchecker.shape == (hs, ws)
    assert caps.design_hash == d.hash
    assert len(caps.meta["white"]) == len(caps.meta["line"]) == L
    assert all(m["design_hash"] == d.hash for m in caps.meta["line"])
    assert [m["monochromatic_nm"] for m in caps.meta["line"]] == list(d.wavelengths)
    assert caps.meta["checker"]["pattern_size"] == [7, 7] == list(caps.pattern_size)
    assert caps.meta["checker"]["squares"] == [8, 8]
    # Band-pass whites: each lights its own band only, and every band lights the views.
    assert all(m["band_nm"] == w for m, w in zip(caps.meta["white"], d.wavelengths))
    assert np.all(caps.white.max(axis=(1, 2)) > 0.5 * d.max_dn)
    assert caps.patch_radiance.shape == (24, L) and np.all(caps.patch_radiance > 0)
    assert len(caps.names()) == 2 * L + 3
    # The monochromatic captures' transports are dropped once used: only band-pass ones
    # (every band's interval) stay in memory; so are the captures' on request.
    from kaleidospec.instrument import release_transports

    kept = [transport._MEMO[k] for k in set(transport._MEMO) - before]
    assert kept and all(tr.intervals.shape[0] == L for tr in kept)
    release_transports("captures")
    assert all(tr.maps.seed != transport.SEEDS["captures"] for tr in transport._MEMO.values())


def test_captures_without_keeping_the_transport_are_the_same_captures():
    """``keep_transport=False`` drops the band-pass transport before the monochromatic
    captures (memory) and changes no capture: each keeps its own noise seed; the lines handed
    one at a time to ``on_line`` (not kept) are the same frames too."""
    from kaleidospec.instrument import release_transports
    from sim.transport import exact as transport

    d = get_design("small", OVR)
    kept = render_captures(d, repeats=1)
    release_transports("captures")
    before = set(transport._MEMO)
    handed = {}

    def on_line(l, frame, whites):
        # The whites are complete when the lines come.
        np.testing.assert_array_equal(whites, kept.white)
        handed[l] = frame.copy()

    lean = render_captures(d, repeats=1, keep_transport=False, on_line=on_line)
    assert set(transport._MEMO) - before == set()
    for name in ("white", "checker", "checker_white", "colorchecker"):
        np.testing.assert_array_equal(getattr(lean, name), getattr(kept, name), err_msg=name)
    # The lines handed to ``on_line`` one at a time, not kept, are the stack's frames.
    assert lean.line is None and sorted(handed) == list(range(d.n_bands))
    np.testing.assert_array_equal(np.stack([handed[l] for l in range(d.n_bands)]), kept.line)
    assert lean.meta["line"] == kept.meta["line"]
