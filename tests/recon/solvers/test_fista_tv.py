"""FISTA-TV (recon.solvers.fista_tv)."""

import numpy as np
import pytest

from cases import piecewise_cube
from recon.metrics import psnr
from recon.solvers import fista_tv, twist


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
