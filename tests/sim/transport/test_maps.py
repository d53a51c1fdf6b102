"""The traced optical maps: wavelength nodes, fits at the float32 round-off, the relay."""

from __future__ import annotations

import numpy as np
import pytest

from sim.optics.design import get_design

SMALL = get_design("small")


def test_band_nodes_keep_the_dispersion_within_the_tolerance():
    from sim.bands import band_intervals
    from sim.transport.maps import band_nodes, panel_path_error

    for d in (SMALL, get_design("paper")):
        iv = band_intervals(d)
        for tol in (0.003, 2e-4):
            nodes, index = band_nodes(d, iv, tol)
            assert np.all(np.diff(nodes) > 0)
            for (lo, hi), idx in zip(iv, index):
                nb = nodes[idx]
                assert nb[0] == pytest.approx(lo) and nb[-1] == pytest.approx(hi)
                assert len(idx) % 2 == 1 and len(idx) >= 3
                np.testing.assert_allclose(np.diff(nb), (hi - lo) / (len(idx) - 1))
                t = np.linspace(0.0, 1.0, 301)
                panels = list(zip(nb[:-1:2], nb[2::2]))
                err = max(panel_path_error(d.dispersion_px_at(a + t * (b - a)), t)
                          for a, b in panels)
                assert err <= tol
                if len(panels) > 1:     # and no more panels than that takes
                    fewer = np.linspace(lo, hi, len(panels))
                    assert max(panel_path_error(d.dispersion_px_at(a + t * (b - a)), t)
                               for a, b in zip(fewer[:-1], fewer[1:])) > tol
            # Neighbouring bands share their common edge.
            assert sum(len(i) for i in index) - (len(index) - 1) == nodes.size
        # The shipped tolerance takes one panel a band on both designs.
        assert all(len(i) == 3 for i in band_nodes(d, iv, 0.003)[1])
    # A monochromatic band is one node.
    nodes, index = band_nodes(SMALL, [[550.0, 550.0]])
    assert nodes.tolist() == [550.0] and index[0].tolist() == [0]


def test_panel_path_error_is_zero_on_the_path_and_sees_a_cubic():
    from sim.transport.maps import panel_path_error

    t = np.linspace(0.0, 1.0, 201)
    # A path whose t is quadratic in x: x(t) solves t = x/2 + 0.01 x (x − 2) on [0, 2].
    x = np.linspace(0.0, 2.0, 4001)
    tx = x / 2 + 0.01 * x * (x - 2)
    assert panel_path_error(np.interp(t, tx, x), t) < 1e-6
    # A straight path, and a cubic wiggle of 0.01 about it.
    assert panel_path_error(3.0 * t, t) < 1e-12
    wiggle = 0.01 * t * (t - 0.5) * (t - 1) / 0.048112522
    assert 0.009 < panel_path_error(3.0 * t + wiggle, t) < 0.011


def test_legendre_values_are_the_legendre_polynomials():
    from numpy.polynomial import legendre

    from sim.transport.maps import legendre_values

    x = np.linspace(-1.2, 1.2, 7)
    got = legendre_values(x, 5)
    for k in range(6):
        np.testing.assert_allclose(got[:, k], legendre.legval(x, np.eye(6)[k]), atol=1e-12)


@pytest.mark.mitsuba
def test_maps_are_fitted_to_the_round_off_and_the_relay_is_the_minification(shared_cache,
                                                                            monkeypatch):
    pytest.importorskip("mitsuba")
    from sim.transport.exact import load_or_build

    monkeypatch.setenv("KALEIDOSPEC_CACHE", str(shared_cache))
    d = SMALL
    m = load_or_build(d, seed=0).maps
    # Mask positions within 1e-3 px (float32 round-off of 400 mm coordinates: ~5e-4 px per
    # ray); the relay's affine map within 1e-3 px; the throughput within 0.1 %.
    assert m.fit_rms[:, :3].max() < 1e-3 and m.fit_rms[:, 3].max() < 1e-3, m.fit_rms
    # u = α + β m: |β| is a mask cell over the relay's minification, in scene sides.
    from sim.optics.diffuser import cube_region

    side = cube_region(d, (1, 1)).dx
    beta = d.mask_pitch_um * 1e-3 / d.minification / side
    from sim.optics.design import VIEW_GRID

    for k, vid in enumerate(m.views):
        r, c = VIEW_GRID[vid]
        for q, flipped in ((1, c != 1), (3, r != 1)):
            assert abs(abs(m.relay[k, q]) / beta - 1) < 1e-4, (vid, q)
            # The centre view is upright; a mirrored copy reverses the axis it flips.
            assert (m.relay[k, q] < 0) == flipped
