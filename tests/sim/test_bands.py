"""sim.bands: the scene cube's one-pass check and its bands' maxima."""

import numpy as np
import pytest

from recon.errors import InputError
from sim.bands import check_cube
from sim.optics.design import get_design

SMALL = get_design("small")


def test_peaks_are_each_bands_maximum_in_any_layout():
    wl = SMALL.wavelengths
    rng = np.random.default_rng(0)
    cube = rng.random((40, 30, wl.size)).astype(np.float32)
    cube[:, :, 3] = 0.0                                     # a dark band
    for c in (cube, cube[::2, 1::3], np.asfortranarray(cube), cube.astype(np.float64)):
        out, w, peaks = check_cube(SMALL, c, wl, peaks=True)
        assert out.dtype == np.float32 and peaks.dtype == np.float32
        np.testing.assert_array_equal(peaks, np.asarray(c, np.float32).max(axis=(0, 1)))
        np.testing.assert_array_equal(w, wl)
    assert peaks[3] == 0.0
    assert len(check_cube(SMALL, cube, wl)) == 2            # peaks only when asked


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_single_non_finite_value_anywhere_is_refused(value):
    wl = SMALL.wavelengths
    cube = np.ones((9, 7, wl.size), np.float32)
    for at in ((0, 0, 0), (8, 6, wl.size - 1), (4, 3, 5)):
        bad = cube.copy()
        bad[at] = value
        with pytest.raises(InputError, match="non-finite"):
            check_cube(SMALL, bad, wl)


def test_negative_and_out_of_range_radiance_is_refused():
    wl = SMALL.wavelengths
    cube = np.ones((9, 7, wl.size), np.float64)
    cube[2, 2, 2] = -1e-30
    with pytest.raises(InputError, match="negative"):
        check_cube(SMALL, cube, wl)
    cube[2, 2, 2] = 1e300                                   # infinite once in float32
    with pytest.raises(InputError, match="non-finite"):
        check_cube(SMALL, cube, wl)
    with pytest.raises(InputError, match="real numbers"):
        check_cube(SMALL, np.ones((3, 3, wl.size), np.complex64), wl)


def test_a_large_cube_is_checked_on_two_threads_alike(monkeypatch):
    """A cube of 4M values or more is scanned in two halves of its rows on two threads: the
    peaks are still each band's maximum, and a bad value in either half, or on the row where
    the halves meet, is still refused, as on one thread."""
    import recon.kernels

    wl = SMALL.wavelengths
    rng = np.random.default_rng(1)
    n = 640                                             # 640² × 11 bands: 4.5M values
    cube = rng.random((n, n, wl.size)).astype(np.float32)
    cube[n // 2 + 7, 3, 4] = 2.0                        # band 4's peak in the second half
    cube[:, :, 6] = 0.0
    for one in (False, True):
        if one:
            monkeypatch.setattr(recon.kernels, "cores", lambda: 1)
        _, _, peaks = check_cube(SMALL, cube, wl, peaks=True)
        np.testing.assert_array_equal(peaks, cube.max(axis=(0, 1)))
        assert peaks[4] == 2.0 and peaks[6] == 0.0
        for row in (0, n // 2 - 1, n // 2, n - 1):
            for value, what in ((np.nan, "non-finite"), (-np.inf, "non-finite"),
                                (-0.5, "negative")):
                bad = cube.copy()
                bad[row, n // 3, 9] = value
                with pytest.raises(InputError, match=what):
                    check_cube(SMALL, bad, wl)
