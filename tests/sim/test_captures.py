"""Calibration captures: the checkerboard target, averaging of repeats, the capture set."""

import os

import numpy as np
import pytest

from sim.captures import CHECKER_NM, capture, checker_target, render_captures
from sim.design import get_design

OVR = {"band_step_nm": 50.0}


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory):
    old = os.environ.get("KALEIDOSPEC_CACHE")
    os.environ["KALEIDOSPEC_CACHE"] = str(tmp_path_factory.getbasetemp() / "kaleidospec-cache")
    yield
    if old is None:
        os.environ.pop("KALEIDOSPEC_CACHE", None)
    else:
        os.environ["KALEIDOSPEC_CACHE"] = old


def test_checker_target_fits_every_code_region():
    d = get_design("small", OVR)
    cube, (cols, rows) = checker_target(d)
    v = d.view_size_px
    assert cube.shape == (v, v, d.n_bands) and cube.dtype == np.float32
    dark = cube[:, :, 0] < 0.5
    ys, xs = np.nonzero(dark)
    # The board (with its dark squares) leaves a white quiet zone on every side, inside the
    # columns every view codes (the centre codes [0, v - guard), a mirrored view [guard, v)).
    g = d.guard_px
    assert ys.min() > 0 and ys.max() < v - 1
    assert xs.min() >= g and xs.max() < v - g
    assert (cols, rows) == (7, 7)


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


def test_render_captures_is_complete_and_tagged():
    d = get_design("small", OVR)
    caps = render_captures(d, repeats=1)
    L = d.n_bands
    hs, ws = d.sensor_height_px, d.sensor_width_px
    assert caps.white.shape == caps.line.shape == (L, hs, ws)
    assert caps.checker.shape == caps.checker_white.shape == caps.colorchecker.shape == (hs, ws)
    assert caps.design_hash == d.hash
    assert len(caps.meta["white"]) == len(caps.meta["line"]) == L
    assert all(m["design_hash"] == d.hash for m in caps.meta["line"])
    assert [m["monochromatic_nm"] for m in caps.meta["line"]] == list(d.wavelengths)
    assert caps.meta["checker"]["pattern_size"] == [7, 7]
    # Band-pass whites: each lights its own band only, and every band lights the views.
    assert all(m["band_nm"] == w for m, w in zip(caps.meta["white"], d.wavelengths))
    assert np.all(caps.white.max(axis=(1, 2)) > 0.5 * d.max_dn)
    assert caps.patch_radiance.shape == (24, L) and np.all(caps.patch_radiance > 0)
    assert len(caps.names()) == 2 * L + 3
