"""The calibrated models' grids: the truth moved onto the reconstruction grid."""

import numpy as np
import pytest


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


def test_truth_on_grid_matches_the_reconstruction_grid(setup):
    from kaleidospec.models import truth_on_grid
    from kaleidospec.reconstruct import reconstruct_views

    d, cal, frame, meta, truth, wl = setup
    tg = truth_on_grid(truth, d, cal)
    assert tg.shape == tuple(cal.cube_shape)
    cube, _ = reconstruct_views(frame, meta, cal, 1, iters=20)
    # The reconstruction correlates best with the truth at zero shift (registration is right).
    a, b = cube.mean(axis=2)[8:-8, 8:-8], tg.mean(axis=2)
    corr = {}
    for dx in (-2, 0, 2):
        bb = b[8:-8, 8 + dx:b.shape[1] - 8 + dx]
        corr[dx] = np.corrcoef(a.ravel(), bb.ravel())[0, 1]
    assert corr[0] > max(corr[-2], corr[2])


@pytest.mark.parametrize("offset, scale", [(-2.3, 2.0), (0.4, 1.0), (1.75, 3.0), (-0.5, 2.0)])
def test_shifted_area_weights_are_the_area_mean_of_the_cells(offset, scale):
    from kaleidospec.models import shifted_area_weights

    n_in, n_out, up = 24, 9, 40
    x = np.random.default_rng(1).random(n_in)
    w = shifted_area_weights(n_in, n_out, offset, scale)
    # Brute force: the texels on a fine grid, edge-padded, averaged over each cell.
    pad = 8 * up
    fine = np.pad(np.repeat(x, up), pad, mode="edge")
    ref = [fine[pad + round((i + offset) * scale * up):
                pad + round((i + 1 + offset) * scale * up)].mean() for i in range(n_out)]
    np.testing.assert_allclose(w @ x, ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)


def _box_mean(image, y0, y1, x0, x1):
    """Mean of a piecewise-constant image over [y0, y1] x [x0, x1] (texel units) from its
    integral image, which is bilinear within each texel."""
    from scipy.interpolate import RegularGridInterpolator

    s = np.zeros((image.shape[0] + 1, image.shape[1] + 1))
    s[1:, 1:] = image.astype(np.float64).cumsum(0).cumsum(1)
    f = RegularGridInterpolator((np.arange(s.shape[0]), np.arange(s.shape[1])), s)
    total = f([[y1, x1]])[0] - f([[y0, x1]])[0] - f([[y1, x0]])[0] + f([[y0, x0]])[0]
    return total / ((y1 - y0) * (x1 - x0))


def test_truth_on_grid_keeps_the_detail_within_a_pixel(setup):
    """From the scene at twice the grid the truth is the exact area mean over the grid's cells;
    from the scene's mean on the design grid it is that mean linearly interpolated (what the
    truth used to be), which smooths the detail away."""
    from kaleidospec.models import grid_offset, truth_on_grid
    from sim.frame import ground_truth

    d, cal, *_ = setup
    v = d.view_size_px
    scene = np.random.default_rng(2).random((2 * v, 2 * v, cal.n_bands)).astype(np.float32)
    oy, ox = grid_offset(d, cal)
    h, w = cal.cube_shape[:2]
    fine = truth_on_grid(scene, d, cal)
    coarse = truth_on_grid(ground_truth(d, scene), d, cal)
    assert fine.shape == coarse.shape == (h, w, cal.n_bands)
    for y, x in ((5, 7), (h // 2, w // 3), (h - 9, w - 12)):
        ref = _box_mean(scene[..., 1], 2 * (y + oy), 2 * (y + 1 + oy), 2 * (x + ox),
                        2 * (x + 1 + ox))
        assert abs(fine[y, x, 1] - ref) < 1e-5
    # From the design grid's means: their linear interpolation, no longer the scene's mean.
    gt = ground_truth(d, scene)[..., 1].astype(np.float64)
    iy, ix = int(np.floor(oy)), int(np.floor(ox))
    fy, fx = oy - iy, ox - ix
    y, x = h // 2, w // 3
    a = gt[y + iy:y + iy + 2, x + ix:x + ix + 2]
    lin = ((1 - fy) * ((1 - fx) * a[0, 0] + fx * a[0, 1])
           + fy * ((1 - fx) * a[1, 0] + fx * a[1, 1]))
    assert abs(coarse[y, x, 1] - lin) < 1e-5
    assert np.abs(coarse - fine)[4:-4, 4:-4].mean() > 0.02
