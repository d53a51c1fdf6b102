"""TwIST (recon.solvers.twist)."""

import math

import numpy as np
import pytest

from recon.operators import kaleidoscope_cassi, standard_cassi
from recon.solvers import twist, twist_parameters


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


def test_parameters_follow_bioucas_dias_figueiredo():
    alpha, beta = twist_parameters(1e-4)
    rho0 = (1 - 1e-4) / (1 + 1e-4)
    assert alpha == pytest.approx(2 / (1 + math.sqrt(1 - rho0**2)))
    assert beta == pytest.approx(2 * alpha / (1 + 1e-4))
    assert 1 < alpha < 2


@pytest.mark.parametrize("key,floor", [("standard", 19.0), ("kaleido3", 27.0)])
def test_reconstructs_and_is_monotone(ops, key, floor):
    op, truth = ops[key], piecewise_cube()
    g = op.forward(truth)
    res = twist(op, g, iters=60, tau=0.05)
    assert psnr(res.x, truth) > floor
    assert psnr(res.x, truth) > psnr(op.adjoint(g), truth) + 15
    obj = np.array(res.objective)
    assert len(obj) == 60
    assert np.all(np.diff(obj) <= 0)


def test_underestimated_norm_is_doubled_and_stays_monotone(ops):
    op, truth = ops["standard"], piecewise_cube()
    res = twist(op, op.forward(truth), iters=20, tau=0.05, max_svd=0.05)
    assert res.info["svd_doublings"] > 0
    assert np.all(np.diff(res.objective) <= 0)


def test_objective_matches_definition(ops):
    from recon.solvers import objective

    op, truth = ops["kaleido3"], piecewise_cube()
    g = op.forward(truth).astype(np.float64)
    res = twist(op, g, iters=5, tau=0.05)
    assert res.objective[-1] == pytest.approx(objective(op, g, res.x, 0.05), rel=1e-9)
