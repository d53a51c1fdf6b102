"""tools/exp_minimum.py: the primal-dual reference solver reaches the objective's minimum."""

from __future__ import annotations

import numpy as np
import pytest
from tool_scripts import load_tool

from recon.operators.base import MatrixOperator
from recon.solvers import fista_tv, objective

SHAPE = (2, 6, 5)


def _problem(seed: int = 3):
    """A non-negative operator with fewer rows than unknowns (TV decides the rest)."""
    rng = np.random.default_rng(seed)
    n = int(np.prod(SHAPE))
    h = rng.random((40, n)).astype(np.float32) * (rng.random((40, n)) < 0.3)
    op = MatrixOperator(h, ishape=SHAPE, oshape=(40,))
    truth = np.zeros(SHAPE, np.float32)
    truth[:, 1:4, 2:] = 1.0
    truth[1] *= 0.5
    g = op.forward(truth) + 0.01 * rng.standard_normal(40).astype(np.float32)
    return op, g


def test_primal_dual_reaches_the_minimum_that_a_long_fista_finds():
    """Against FISTA run far past convergence with a nearly exact prox (200 dual
    iterations a step): the same objective value, to 1e-4 of it, and on the way there."""
    op, g = _problem()
    tau = 0.05
    tool = load_tool("exp_minimum")
    values = {}
    x = tool.pdhg_tv(op, g, tau, 4000, theta=3.0,
                     callback=lambda k, x: values.__setitem__(k, objective(op, g, x, tau)))
    ref = fista_tv(op, g, tau=tau, iters=4000, tv_iters=200, metric="scalar").x
    f_ref = objective(op, g, ref, tau)
    assert objective(op, g, x, tau) == pytest.approx(f_ref, rel=1e-4)
    # Still far from it early: the comparison is not won by the start.
    assert values[10] > f_ref * 1.01


def test_an_operator_with_negative_entries_is_refused():
    op, g = _problem()
    neg = MatrixOperator(-np.asarray(op.matrix), ishape=SHAPE, oshape=(40,))
    with pytest.raises(ValueError, match="negative"):
        load_tool("exp_minimum").pdhg_tv(neg, g, 0.05, 5)


@pytest.mark.parametrize("scales", ["0.5,x", "0,1", "-1"])
def test_bad_tau_scales_are_refused_before_any_work(scales, capsys):
    with pytest.raises(SystemExit) as e:
        load_tool("exp_minimum").main(["--tau-scales", scales])
    assert e.value.code == 2 and "--tau-scales" in capsys.readouterr().err
