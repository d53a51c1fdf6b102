"""TwIST (recon.solvers.twist)."""

import math

import numpy as np
import pytest

from cases import DriftingTV, piecewise_cube
from recon.metrics import psnr
from recon.operators.base import LinearOperator
from recon.solvers import twist, twist_parameters


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


def test_monotone_test_scores_the_iterate_with_the_current_state(ops):
    # As FISTA's restart test (test_fista_tv): after a prox that moved the prior's state, the
    # iterate the monotone test compares with is scored with the new state, so a state that
    # lifts every value alike rejects no step and the iterates are those without a state.
    op, truth = ops["kaleido3"], piecewise_cube()
    g = op.forward(truth)
    plain = twist(op, g, iters=60, tol=None, prior=DriftingTV(0.05, 0.0, reports_state=False))
    drifting = twist(op, g, iters=60, tol=None, prior=DriftingTV(0.05, 0.5, reports_state=True))
    assert drifting.info["rejected"] == plain.info["rejected"]
    assert drifting.info["svd_doublings"] == plain.info["svd_doublings"]
    np.testing.assert_allclose(drifting.x, plain.x, rtol=0, atol=1e-5 * float(np.abs(plain.x).max()))


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


class CountingOp(LinearOperator):
    """Wraps an operator and counts forwards and adjoints."""

    def __init__(self, op):
        super().__init__(op.ishape, op.oshape)
        self.op = op
        self.n_forward = self.n_adjoint = 0

    def _forward(self, x):
        self.n_forward += 1
        return self.op.forward(x)

    def _adjoint(self, y):
        self.n_adjoint += 1
        return self.op.adjoint(y)


@pytest.mark.parametrize("lam1", [1e-4, 1e-2])
def test_one_forward_and_one_adjoint_per_iteration(ops, lam1):
    # Rejected two-step candidates reuse the residual of Gamma(f_t) (linearity), so the cost
    # per iteration is one forward and one adjoint, plus one forward per prox refinement or
    # doubling of max_svd.
    op = CountingOp(ops["kaleido3"])
    truth = piecewise_cube()
    g = ops["kaleido3"].forward(truth)
    s = twist(ops["kaleido3"], g, iters=1, tau=0.05).info["max_svd"]
    res = twist(op, g, iters=40, tau=0.05, lam1=lam1, max_svd=s)
    extra = res.info["prox_refinements"] + res.info["svd_doublings"]
    assert res.info["rejected"] > 0 or lam1 == 1e-2
    assert op.n_adjoint == 1 + 40  # the start H^T g, then one gradient per iteration
    assert op.n_forward == 1 + 40 + extra


def test_combined_residual_matches_a_fresh_forward_float32(ops):
    # The candidate's residual is a linear combination of earlier ones; after many accepted
    # two-step updates in float32 it still gives the objective of a fresh forward.
    from recon.solvers import objective

    op, truth = ops["kaleido3"], piecewise_cube()
    g = op.forward(truth)
    res = twist(op, g, iters=80, tau=0.05)
    assert res.objective[-1] == pytest.approx(objective(op, g, res.x, 0.05), rel=1e-5)
    assert np.all(np.diff(res.objective) <= 0)


def test_default_parameters_and_callback_semantics(ops):
    from recon.solvers.twist import DEFAULT_LAM1

    op, truth = ops["standard"], piecewise_cube()
    g = op.forward(truth)
    seen = []
    res = twist(op, g, iters=12, tau=0.05,
                callback=lambda it, x, info: seen.append((it, info["objective"])) or it == 7)
    assert (res.info["alpha"], res.info["beta"]) == pytest.approx(twist_parameters(DEFAULT_LAM1))
    assert res.info["tv_iters"] % 2 == 0  # a warm dual wants an even count
    assert res.iterations == 7 and [i for i, _ in seen] == list(range(1, 8))
    assert [f for _, f in seen] == res.objective


def test_norm_estimate_brackets_the_top_eigenvalue():
    from recon.operators.base import MatrixOperator
    from recon.solvers.twist import norm_estimate

    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((60, 60)))
    sv = np.concatenate([[3.0, 2.9, 2.7], rng.uniform(0, 2, 57)])
    a = MatrixOperator((q * sv) @ np.linalg.qr(rng.standard_normal((60, 60)))[0],
                       ishape=(60,), oshape=(60,))
    top = sv.max() ** 2
    est = norm_estimate(a, n_iter=8, safety=1.0)
    assert 0.9 * top <= est <= top * (1 + 1e-6)  # a Ritz value: below, and close
    # An invariant Krylov space (rank-one operator) gives the exact value and stops early.
    u = rng.standard_normal(20)
    r1 = MatrixOperator(np.outer(u, u), ishape=(20,), oshape=(20,))
    assert norm_estimate(r1, n_iter=5, safety=1.0) == pytest.approx(np.vdot(u, u) ** 2, rel=1e-5)
    zero = MatrixOperator(np.zeros((4, 5)), ishape=(5,), oshape=(4,))
    assert norm_estimate(zero, n_iter=3) == 0.0


def test_norm_estimate_beats_power_iteration_on_cassi(ops):
    from recon.solvers import operator_norm_sq
    from recon.solvers.twist import norm_estimate

    op = ops["kaleido3"]
    g = op.forward(piecewise_cube())
    lanczos = norm_estimate(op, op.adjoint(g), n_iter=6, safety=1.0)
    power = operator_norm_sq(op, n_iter=15) / 1.02
    assert lanczos >= power * 0.999
    assert lanczos <= operator_norm_sq(op, n_iter=200) / 1.02 * (1 + 1e-4)
