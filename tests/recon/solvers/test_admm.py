"""ADMM (recon.solvers.admm): with the TV prior it reaches FISTA's minimiser of the same
objective; its exact x step is the solve it replaces; bad input is an error."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import standard_cassi
from recon.solvers import admm, fista_tv, objective
from recon.solvers.admm import _CG, _diagonal_gram, _exact_step

L, H, W = 3, 10, 9


def _cube(seed=4):
    rng = np.random.default_rng(seed)
    x = np.full((L, H, W), 0.2)
    x[:, 2:7, 3:8] = 0.8
    return x + 0.05 * rng.standard_normal(x.shape)


@pytest.mark.parametrize("opname", ["standard", "kaleido3"])
@pytest.mark.parametrize("exact", [None, False])
def test_tv_reaches_fistas_minimiser(small_ops, opname, exact):
    op = small_ops[opname]
    rng = np.random.default_rng(5)
    g = op.forward(_cube()) + 0.01 * rng.standard_normal(op.oshape)
    tau = 0.05
    ref = fista_tv(op, g, iters=3000, tau=tau, tv_iters=10, tol=1e-12).x
    res = admm(op, g, iters=400, tau=tau, exact=exact)
    assert res.info["exact"] is (opname == "standard" and exact is None)
    # Measured: 1.4e-4 to 2.7e-4; a TV weight 10 % off moves the minimiser by 5e-3 to 1e-2.
    assert np.linalg.norm(res.x - ref) / np.linalg.norm(ref) < 1e-3
    f_ref = objective(op, g, ref, tau)
    assert abs(objective(op, g, res.x, tau) - f_ref) < 1e-4 * f_ref


def test_exact_step_solves_the_regularised_normal_equations(small_ops):
    op = small_ops["standard"]
    rng = np.random.default_rng(6)
    b = rng.standard_normal(op.ishape)
    phi = _diagonal_gram(op, np.float64, None)
    assert phi is not None
    x = _exact_step(op, phi, 0.7, b, out=np.empty_like(b))
    back = op.adjoint(op.forward(x)) + 0.7 * x
    np.testing.assert_allclose(back, b, atol=1e-10)
    assert _diagonal_gram(small_ops["kaleido3"], np.float64, None) is None
    assert _diagonal_gram(op, np.float64, False) is None


def test_cg_solves_the_regularised_normal_equations(small_ops):
    op = small_ops["kaleido3"]
    rng = np.random.default_rng(7)
    b = rng.standard_normal(op.ishape)
    x = np.zeros_like(b)
    _CG(op, np.float64).solve(0.3, b, x, 200)
    np.testing.assert_allclose(op.adjoint(op.forward(x)) + 0.3 * x, b, atol=1e-9)


def test_rho_and_its_adaptation(small_ops):
    op = small_ops["kaleido3"]
    g = op.forward(_cube())
    fixed = admm(op, g, iters=20, tau=0.05, rho=0.4, adapt=0)
    assert fixed.info["rho"] == 0.4 and fixed.info["rho_changes"] == 0
    # A penalty far too small: the primal residual dominates and rho is raised.
    low = admm(op, g, iters=20, tau=0.05, rho=1e-4, adapt=3)
    assert low.info["rho_changes"] == 3 and low.info["rho"] == pytest.approx(8e-4)


@pytest.mark.parametrize("kw,match", [({"rho": 0.0}, "rho"), ({"rho": -1.0}, "rho"),
                                      ({"rho": float("nan")}, "rho"),
                                      ({"cg_iters": 0}, "cg_iters"), ({"adapt": -1}, "adapt"),
                                      ({"cg_iters": 1.5}, "cg_iters")])
def test_bad_parameters(small_ops, kw, match):
    op = small_ops["standard"]
    with pytest.raises(InputError, match=match):
        admm(op, op.forward(_cube()), iters=2, **kw)


def test_exact_needs_a_diagonal_gram(small_ops):
    op = small_ops["kaleido3"]
    with pytest.raises(InputError, match="diagonal"):
        admm(op, op.forward(_cube()), iters=2, exact=True)


def test_zero_operator(small_ops):
    op = standard_cassi(np.zeros((H, W), np.float32), 1, L)
    with pytest.raises(InputError, match="operator is zero"):
        admm(op, np.ones(op.oshape, np.float32), iters=2)
