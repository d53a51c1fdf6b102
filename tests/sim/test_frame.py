"""sim.frame: the expected frame summed view region by view region equals the whole-sensor sum."""

from __future__ import annotations

import numpy as np
import pytest

from sim import sensor


def test_view_regions_cover_the_widened_views_once():
    rects = [(2, 3, 10, 12), (13, 3, 10, 12), (2, 16, 21, 5), (40, 40, 10, 10), (0, 0, 1, 1)]
    shape = (45, 48)
    for reach in (0, 1, 3):
        want = np.zeros(shape, bool)
        for r0, c0, h, w in rects:
            want[max(r0 - reach, 0):r0 + h + reach, max(c0 - reach, 0):c0 + w + reach] = True
        count = np.zeros(shape, int)
        for r0, r1, c0, c1 in sensor.view_regions(rects, reach, shape):
            assert 0 <= r0 < r1 <= shape[0] and 0 <= c0 < c1 <= shape[1]
            count[r0:r1, c0:c1] += 1
        # Every widened view's pixel once (neighbours' margins overlap at reach ≥ 1), no other.
        np.testing.assert_array_equal(count, want.astype(int))
    assert sensor.view_regions([], 2, shape) == []


@pytest.mark.mitsuba
@pytest.mark.parametrize("diffraction", [True, False])
def test_electrons_equal_the_whole_sensor_sum(shared_cache, diffraction):
    """Nine views of ``small`` lie 2 px apart, so the blur's margins overlap: the frame summed
    over the regions the views light must still be the whole-sensor sum of before, to the bit.
    Six bands on at most two threads, the blur reaching 1 px in some and 2 px in others, and one
    band dark: each thread's images serve several bands, and nothing of one may leak into the
    next."""
    pytest.importorskip("mitsuba")
    from sim.design import get_design
    from sim.frame import FrameModel

    d = get_design("small").replace(views=tuple(range(9)))
    wl = d.wavelengths[[1, 3, 6, 8, 9, 10]]
    model = FrameModel(d, wl, trace_seed=1, diffraction=diffraction)
    rng = np.random.default_rng(3)
    v = 2 * d.view_size_px
    cube = rng.random((v, v, wl.size)).astype(np.float32)
    cube[:, :, 2] = 0.0
    got = model.electrons(cube)

    tr = model.transport
    want = np.zeros(tr.sensor, np.float32)
    for l in range(wl.size):
        img = tr.band(np.ascontiguousarray(cube[:, :, l]), l)
        if diffraction:
            img = sensor.blur_views(img, model.kernels[l], model.rects)
        img *= model.scale[l]
        want += img
    np.maximum(want, 0.0, out=want)
    assert got.max() > 0
    assert np.array_equal(got, want)
