"""Scores that need the scene: the ColorChecker's patches on the reconstruction grid and their
colour error; the sweep's interpolation of the apex reaching a span."""

import math

import numpy as np
import pytest


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


def test_colorchecker_patches_and_their_colour_error(setup):
    from kaleidospec.evaluate import colorchecker_patches, patch_delta_e2000
    from kaleidospec.models import truth_on_grid

    d, cal, frame, meta, truth, wl = setup
    patches = colorchecker_patches(d, cal)
    h, w, _ = cal.cube_shape
    assert len(patches) >= 12
    tg = truth_on_grid(truth, d, cal)
    for y, x, ph, pw in patches.values():
        assert 0 <= y and y + ph <= h and 0 <= x and x + pw <= w and ph > 1 and pw > 1
        # The middle half of a patch is flat in the truth: one reflectance under one light.
        block = tg[y:y + ph, x:x + pw]
        assert np.allclose(block, block[0, 0], rtol=1e-3, atol=1e-6)
    boxes = list(patches.values())
    assert patch_delta_e2000(tg, tg, boxes, wl) == pytest.approx(0.0, abs=1e-9)
    tinted = tg * np.linspace(0.7, 1.3, tg.shape[2], dtype=np.float32)
    assert patch_delta_e2000(tinted, tg, boxes, wl) > 2.0


def test_smallest_reaching_interpolates():
    from kaleidospec.evaluate import smallest_reaching

    assert smallest_reaching([10, 20, 30], [40, 50, 70]) == pytest.approx(25.0)
    assert smallest_reaching([10, 20], [60, 80]) == 10.0
    assert smallest_reaching([10, 20], [10, 20]) is None
    assert smallest_reaching([10, 20, 30], [40, math.nan, 80]) == pytest.approx(20.0)
