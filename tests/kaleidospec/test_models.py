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


def test_box_means_are_the_exact_means_of_the_texels():
    """Against a brute-force mean of the image refined 64 times (edge-padded): boxes inside,
    across and beyond the image's edges, and a box of no width (the texel at its point)."""
    from kaleidospec.models import box_means

    rng = np.random.default_rng(0)
    img = rng.random((13, 17, 2)).astype(np.float32)
    up, pad = 64, 6

    def q(a):
        return np.round(a * up) / up

    x0, y0 = q(rng.uniform(-3, 18, 60)), q(rng.uniform(-3, 14, 60))
    x1, y1 = x0 + q(rng.uniform(0.1, 4, 60)), y0 + q(rng.uniform(0.1, 4, 60))
    got = box_means(img, x0, x1, y0, y1)
    fine = np.pad(np.repeat(np.repeat(img.astype(np.float64), up, 0), up, 1),
                  ((pad * up,) * 2, (pad * up,) * 2, (0, 0)), mode="edge")

    def cut(a):
        return int(round((a + pad) * up))

    ref = np.array([fine[cut(b0):cut(b1), cut(a0):cut(a1)].mean(axis=(0, 1))
                    for a0, a1, b0, b1 in zip(x0, x1, y0, y1)])
    np.testing.assert_allclose(got, ref, atol=1e-6)
    point = box_means(img, np.array([5.25]), np.array([5.25]), np.array([2.5]), np.array([2.5]))
    np.testing.assert_allclose(point[0], img[2, 5], atol=1e-6)


def test_box_means_compiled_is_the_numpy_loop_to_the_bit():
    """The compiled box means (every video frame's truth on the grid) against the NumPy loop
    they replace: the same bits, boxes inside, across and beyond the edges, narrower than
    10⁻³ texel, and a grid-shaped (2-D) set of boxes."""
    from kaleidospec.models import box_means, box_means_reference
    from recon import kernels

    if not kernels.enabled():
        pytest.skip("Numba not available")
    rng = np.random.default_rng(4)
    img = rng.random((23, 31, 5)).astype(np.float32)
    x0 = rng.uniform(-4, 33, (7, 9))
    y0 = rng.uniform(-4, 25, (7, 9))
    x1 = x0 + rng.uniform(0.0, 5, x0.shape)
    y1 = y0 + rng.uniform(0.0, 5, y0.shape)
    x1[0, :3] = x0[0, :3] + 1e-5
    got = box_means(img, x0, x1, y0, y1)
    ref = box_means_reference(img, x0, x1, y0, y1)
    assert got.shape == (7, 9, 5) and got.dtype == np.float32
    np.testing.assert_array_equal(got, ref)


def test_truth_on_grid_is_the_scene_over_each_grid_cell(setup):
    """From the scene at twice the grid the truth is the exact area mean over each grid cell
    where :func:`grid_on_scene` puts it; from the scene's mean on the design grid the detail
    within a pixel is gone."""
    from kaleidospec.instrument import grid_on_scene
    from kaleidospec.models import truth_on_grid
    from sim.frame import ground_truth

    d, cal, *_ = setup
    v = d.view_size_px
    scene = np.random.default_rng(2).random((2 * v, 2 * v, cal.n_bands)).astype(np.float32)
    h, w = cal.cube_shape[:2]
    x, y = grid_on_scene(d, cal)
    assert x.shape == y.shape == (h + 1, w + 1)
    fine = truth_on_grid(scene, d, cal)
    coarse = truth_on_grid(ground_truth(d, scene), d, cal)
    assert fine.shape == coarse.shape == (h, w, cal.n_bands)
    for i, j in ((5, 7), (h // 2, w // 3), (h - 9, w - 12)):
        x0, x1 = 0.5 * (x[i, j] + x[i + 1, j]), 0.5 * (x[i, j + 1] + x[i + 1, j + 1])
        y0, y1 = 0.5 * (y[i, j] + y[i, j + 1]), 0.5 * (y[i + 1, j] + y[i + 1, j + 1])
        ref = _box_mean(scene[..., 1], 2 * y0, 2 * y1, 2 * x0, 2 * x1)
        assert abs(fine[i, j, 1] - ref) < 1e-5
    # Measured 0.018 (texels uniform in [0, 1]): the design grid's means have lost the
    # sub-pixel detail that the grid's cells, off the design grid by a fraction of a pixel, cut.
    assert np.abs(coarse - fine)[4:-4, 4:-4].mean() > 0.012
