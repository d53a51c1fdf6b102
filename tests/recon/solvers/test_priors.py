"""Every solver takes a prior: the TV prior gives the old call's bits, a quadratic prior with a
closed-form minimiser checks the loops against dense linear algebra, a prior without a value
(a plug-and-play denoiser) runs where the algorithm allows, and bad combinations are errors."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.priors import PriorBase, TVPrior
from recon.solvers import SOLVERS, solve

L, H, W = 3, 10, 9


def _cube(seed=0):
    rng = np.random.default_rng(seed)
    x = np.full((L, H, W), 0.2)
    x[:, 2:7, 3:8] = 0.8
    return (x + 0.05 * rng.standard_normal(x.shape)).astype(np.float32)


class Quadratic(PriorBase):
    r""":math:`\varphi(x) = \frac w2\|x\|^2`; prox :math:`v/(1+sw)`.  ``valued=False`` hides
    the value (as a plug-and-play denoiser does)."""

    name = "quadratic"

    def __init__(self, w, valued=True):
        self.w, self.valued = w, valued

    def prox(self, v, step, out=None):
        out = np.empty_like(v) if out is None else out
        np.multiply(v, 1.0 / (1.0 + step * self.w), out=out)
        return out

    def value(self, x):
        return 0.5 * self.w * float(np.vdot(x, x)) if self.valued else None


def _dense(op):
    n = int(np.prod(op.ishape))
    eye = np.eye(n)
    return np.stack([op.forward(eye[i].reshape(op.ishape)).ravel() for i in range(n)], axis=1)


def _ridge(op, g, w):
    """argmin 1/2 |g - Hx|^2 + w/2 |x|^2 by dense linear algebra."""
    h = _dense(op).astype(np.float64)
    n = h.shape[1]
    return np.linalg.solve(h.T @ h + w * np.eye(n), h.T @ g.ravel()).reshape(op.ishape)


CASES = [("twist", {}), ("twist", {"tau": 0.05, "tv_iters": 4, "isotropic": False}),
         ("fista-tv", {}), ("fista-tv", {"tau": 0.02, "warm_dual": False, "objective": True}),
         ("gap-tv", {}), ("gap-tv", {"tau": 0.2, "accelerate": False, "tv_iters": 3}),
         ("admm", {}), ("admm", {"tau": 0.05, "exact": False})]


@pytest.mark.parametrize("opname", ["standard", "kaleido3"])
@pytest.mark.parametrize("name,kw", CASES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_tv_prior_gives_the_bits_of_the_tv_options(small_ops, opname, name, kw, dtype):
    op = small_ops[opname]
    if name == "admm" and kw.get("exact") is False and opname == "kaleido3":
        pytest.skip("same as the default there")
    g = (op.forward(_cube()) + 0.01).astype(dtype)
    kw = dict(kw)
    tau = kw.pop("tau", None)
    tv = {k: kw.pop(k) for k in ("tv_iters", "warm_dual", "isotropic") if k in kw}
    old = solve(name, op, g, iters=12, tau=tau, **tv, **kw)
    weight = tau if tau is not None else {"gap-tv": 0.1}.get(name, 0.15)
    prior = TVPrior(weight, iters=tv.get("tv_iters", 2), warm=tv.get("warm_dual", True),
                    isotropic=tv.get("isotropic", True))
    new = solve(name, op, g, iters=12, prior=prior, **kw)
    np.testing.assert_array_equal(new.x, old.x)
    assert new.objective == old.objective
    by_name = solve(name, op, g, iters=12, prior="tv", tau=tau, **tv, **kw)
    np.testing.assert_array_equal(by_name.x, old.x)
    assert new.info["prior"] == "tv" and new.info["weight"] == weight


def test_a_prior_object_is_reset_between_solves(small_ops):
    op = small_ops["kaleido3"]
    g = op.forward(_cube())
    prior = TVPrior(0.1)
    a = solve("fista-tv", op, g, iters=8, prior=prior).x
    b = solve("fista-tv", op, g, iters=8, prior=prior).x
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name,kw,iters", [("fista-tv", {}, 3000), ("twist", {}, 3000),
                                           ("admm", {}, 400), ("admm", {"exact": False}, 400)])
@pytest.mark.parametrize("opname", ["standard", "kaleido3"])
def test_quadratic_prior_reaches_the_dense_minimiser(small_ops, opname, name, kw, iters):
    op = small_ops[opname]
    g = op.forward(_cube(1).astype(np.float64)) + 0.02
    w = 0.05
    want = _ridge(op, g, w)
    got = solve(name, op, g, iters=iters, prior=Quadratic(w), tol=1e-13, **kw).x
    assert np.linalg.norm(got - want) / np.linalg.norm(want) < 1e-5


@pytest.mark.parametrize("name", ["fista-tv", "admm"])
def test_prior_without_value_runs_to_the_same_minimiser(small_ops, name):
    op = small_ops["kaleido3"]
    g = op.forward(_cube(2).astype(np.float64))
    want = _ridge(op, g, 0.05)
    res = solve(name, op, g, iters=3000, prior=Quadratic(0.05, valued=False), tol=1e-13,
                objective=True)
    assert res.objective == []
    assert np.linalg.norm(res.x - want) / np.linalg.norm(want) < 1e-5


def test_gap_takes_a_denoiser_prior(small_ops):
    op = small_ops["standard"]
    g = op.forward(_cube(3))
    res = solve("gap-tv", op, g, iters=10, prior=Quadratic(0.5, valued=False), objective=True)
    assert np.all(np.isfinite(res.x)) and res.objective == []
    # GAP's denoising step is the prox at step 1: with a zero-strength prior it is the plain
    # projection iteration, which fits the data.
    fit = solve("gap-tv", op, g, iters=30, prior=Quadratic(0.0)).x
    assert np.linalg.norm(op.forward(fit) - g) < 1e-3 * np.linalg.norm(g)


def test_twist_refuses_a_prior_without_value(small_ops):
    op = small_ops["standard"]
    with pytest.raises(InputError, match="prior with a value"):
        solve("twist", op, op.forward(_cube()), iters=3, prior=Quadratic(0.1, valued=False))


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_bad_prior_arguments(small_ops, name):
    op = small_ops["standard"]
    g = op.forward(_cube())
    with pytest.raises(InputError, match="set them on the prior"):
        solve(name, op, g, iters=2, prior=TVPrior(0.1), tau=0.1)
    with pytest.raises(InputError, match="set them on the prior"):
        solve(name, op, g, iters=2, prior=TVPrior(0.1), tv_iters=4)
    with pytest.raises(InputError, match="unknown prior 'nope'"):
        solve(name, op, g, iters=2, prior="nope")
    with pytest.raises(InputError, match="must be a recon prior"):
        solve(name, op, g, iters=2, prior=object())
    with pytest.raises(InputError, match="tau"):
        solve(name, op, g, iters=2, tau=-1.0)
    with pytest.raises(InputError, match="tv_iters"):
        solve(name, op, g, iters=2, tv_iters=0)
