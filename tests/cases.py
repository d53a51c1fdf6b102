"""Test problems shared by several test modules (importable: `pythonpath = ["tests"]`)."""

import numpy as np


def piecewise_cube(l=8, h=32, w=32, seed=0):
    """Piecewise-constant band-major cube: a background and four rectangles, flat spectra."""
    rng = np.random.default_rng(seed)
    x = np.empty((l, h, w), np.float32)
    x[:] = 0.3 * rng.uniform(0.5, 1, (l, 1, 1))
    for _ in range(4):
        y0, x0 = rng.integers(0, h - 8), rng.integers(0, w - 8)
        x[:, y0:y0 + rng.integers(6, 14), x0:x0 + rng.integers(6, 14)] = \
            rng.uniform(0.2, 1, (l, 1, 1))
    return x
