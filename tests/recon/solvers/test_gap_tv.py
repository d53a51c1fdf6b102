"""GAP-TV (recon.solvers.gap_tv)."""

import numpy as np
import pytest

from cases import piecewise_cube
from recon.metrics import psnr
from recon.solvers import gap_tv


@pytest.mark.parametrize("key,floor", [("standard", 19.0), ("kaleido3", 27.0)])
def test_reconstructs_piecewise_constant_cube(ops, key, floor):
    op, truth = ops[key], piecewise_cube()
    g = op.forward(truth)
    res = gap_tv(op, g, iters=60, tau=0.05)
    assert psnr(res.x, truth) > floor
    assert psnr(res.x, truth) > psnr(op.adjoint(g), truth) + 15


def test_step_is_exact_projection_for_one_view_and_smaller_for_three(ops):
    truth = piecewise_cube()
    one = gap_tv(ops["standard"], ops["standard"].forward(truth), iters=1, tau=0.05)
    three = gap_tv(ops["kaleido3"], ops["kaleido3"].forward(truth), iters=1, tau=0.05)
    assert one.info["step"] == 1.0
    assert 0.2 < three.info["step"] < 1.0


def test_unit_step_diverges_with_three_views(ops):
    # Why the step is estimated: the diagonal approximation of HH^T overshoots with K > 1.
    op, truth = ops["kaleido3"], piecewise_cube()
    with np.errstate(all="ignore"):
        res = gap_tv(op, op.forward(truth), iters=40, tau=0.05, step=1.0)
    assert not np.all(np.isfinite(res.x)) or psnr(res.x, truth) < 10


def test_first_iteration_improves_on_start(ops):
    op, truth = ops["standard"], piecewise_cube()
    g = op.forward(truth)
    res = gap_tv(op, g, iters=1, tau=0.05)
    start = op.adjoint(g / np.where(op.row_norms_sq() > 0, op.row_norms_sq(), 1))
    assert psnr(res.x, truth) > psnr(start, truth)


def test_plain_and_accelerated_and_objective(ops):
    op, truth = ops["standard"], piecewise_cube()
    g = op.forward(truth)
    acc = gap_tv(op, g, iters=40, tau=0.05, objective=True)
    plain = gap_tv(op, g, iters=40, tau=0.05, accelerate=False, tv_iters=5, warm_dual=False)
    assert len(acc.objective) == 40
    assert acc.objective[-1] < 0.2 * acc.objective[0]
    assert psnr(plain.x, truth) > 15 and psnr(acc.x, truth) > 15
