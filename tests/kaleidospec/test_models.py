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
