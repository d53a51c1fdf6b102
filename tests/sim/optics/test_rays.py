"""The ray walk images exactly: every aperture ray of a sensor point meets the mask and the
diffuser at one point (Mitsuba's ``spawn_ray`` would blur it, see sim.optics.rays)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba


@pytest.mark.parametrize("view", [0, 1, 3])
def test_a_sensor_point_sees_one_mask_point_and_one_diffuser_point(view):
    from sim.optics.design import get_design
    from sim.transport.maps import diffuser_coordinates, mask_coordinates
    from sim.optics.rays import sensor_rays, walk
    from sim.optics.scene import trace_setup

    d = get_design("small")
    setup = trace_setup(d, open_mask=True)
    r0, c0, h, w = d.view_rect(view)
    n = 256
    ap = np.random.default_rng(1).random((2, n))
    wk = walk(setup, sensor_rays(setup, np.full(n, r0 + h / 2), np.full(n, c0 + w / 2), ap,
                                 575.0))
    assert wk.reached.all()
    m = mask_coordinates(d, wk.mask) * d.mask_cell_px          # sensor pixels
    u = diffuser_coordinates(d, wk.diffuser) * d.view_size_px  # scene grid pixels
    # float32 round-off only (spawn_ray's sideways step spreads these over 0.26 and 0.5 px).
    assert np.ptp(m, axis=1).max() < 0.005 and np.ptp(u, axis=1).max() < 0.01
    # One reflection off a side wall for a side view, none for the centre.
    want = {0: (0, 0), 1: (1, 0), 3: (0, 1)}[view]
    assert np.all(wk.walls[0] == want[0]) and np.all(wk.walls[1] == want[1])
