"""FISTA-TV (recon.solvers.fista_tv)."""

import numpy as np
import pytest

from recon.operators import kaleidoscope_cassi, standard_cassi
from recon.solvers import fista_tv, twist


def piecewise_cube(l=8, h=32, w=32, seed=0):
    rng = np.random.default_rng(seed)
    x = np.empty((l, h, w), np.float32)
    x[:] = 0.3 * rng.uniform(0.5, 1, (l, 1, 1))
    for _ in range(4):
        y0, x0 = rng.integers(0, h - 8), rng.integers(0, w - 8)
        x[:, y0:y0 + rng.integers(6, 14), x0:x0 + rng.integers(6, 14)] = \
            rng.uniform(0.2, 1, (l, 1, 1))
    return x


def psnr(x, truth):
    d = x.astype(np.float64) - truth
    return 10 * np.log10(float(truth.max()) ** 2 / np.mean(d * d))


@pytest.fixture(scope="module")
def ops():
    rng = np.random.default_rng(1)
    return {"standard": standard_cassi((rng.random((32, 32)) > 0.5).astype(np.float32), 1, 8),
            "kaleido3": kaleidoscope_cassi((rng.random((3, 32, 32)) > 0.5).astype(np.float32),
                                           np.arange(8, dtype=float), 3)}


@pytest.mark.parametrize("key,floor", [("standard", 19.0), ("kaleido3", 26.0)])
def test_reconstructs_piecewise_constant_cube(ops, key, floor):
    op, truth = ops[key], piecewise_cube()
    g = op.forward(truth)
    res = fista_tv(op, g, iters=60, tau=0.05)
    assert psnr(res.x, truth) > floor
    assert psnr(res.x, truth) > psnr(op.adjoint(g), truth) + 15


def test_reaches_the_same_minimum_as_twist(ops):
    # Both minimise 1/2|g - Hf|^2 + tau TV(f): their objectives must agree after many steps.
    op, truth = ops["standard"], piecewise_cube()
    g = op.forward(truth).astype(np.float64)
    f = fista_tv(op, g, iters=300, tau=0.05, objective=True)
    t = twist(op, g, iters=300, tau=0.05)
    assert f.objective[-1] == pytest.approx(t.objective[-1], rel=0.02)
    assert f.objective[-1] < 0.1 * f.objective[0]
