"""The band metric (recon.solvers.band_metric) and FISTA in it (fista_tv(metric=...))."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import MatrixOperator, kaleidoscope_cassi
from recon.priors import TVPrior, make_prior
from recon.solvers import fista_tv
from recon.solvers.band_metric import (
    BandMetric,
    band_column_norms_sq,
    band_metric,
    band_scalable,
    band_weighted,
)
from recon.solvers.base import objective

SHAPE = (3, 10, 9)
#: Column scales of the three bands: one band seen ten times more weakly than another, as the
#: ends of the spectral range are on the calibrated models.
BAND_SCALE = np.array([0.1, 1.0, 0.3])


@pytest.fixture(scope="module")
def weak_band_op():
    """The three-view kaleidoscope CASSI of the solvers' tests (3 bands, 10 x 9), as a dense
    matrix with its bands' columns scaled by BAND_SCALE."""
    rng = np.random.default_rng(3)
    op = kaleidoscope_cassi((rng.random((3,) + SHAPE[1:]) > 0.5).astype(np.float32),
                            np.arange(SHAPE[0], dtype=float), 3)
    n = int(np.prod(SHAPE))
    m = np.stack([op.forward(e.reshape(SHAPE)).reshape(-1)
                  for e in np.eye(n)], axis=1).astype(np.float64)
    m *= np.repeat(BAND_SCALE, SHAPE[1] * SHAPE[2])[None, :]
    return MatrixOperator(m, ishape=SHAPE, oshape=op.oshape)


def _truth():
    x = np.zeros(SHAPE)
    x[:, 2:7, 3:8] = 1.0
    x[1, :4, :] += 0.5
    return x


def test_column_norms_match_the_matrix(weak_band_op):
    # One Hutchinson probe: each band's mean of diag(H^T H) within four standard errors
    # (for a Rademacher u, the band mean of u * H^T H u has the variance
    # 2 / N^2 * sum over j in the band, k != j of G_jk^2, G = H^T H, N pixels per band).
    h = weak_band_op.matrix
    gram = h.T @ h
    n = SHAPE[1] * SHAPE[2]
    exact = np.diag(gram).reshape(SHAPE[0], n).mean(axis=1)
    off = gram - np.diag(np.diag(gram))
    sigma = np.sqrt(2.0 * (off ** 2).sum(axis=1).reshape(SHAPE[0], n).sum(axis=1)) / n
    est = band_column_norms_sq(weak_band_op, np.float64)
    assert np.all(np.abs(est - exact) <= 4.0 * sigma)
    assert sigma[1] < 0.05 * exact[1]      # the strong band is pinned down ...
    # ... and the bands' order of magnitude, what the metric needs, comes out (100x exactly).
    assert est[1] / est[0] > 30.0


def test_metric_majorises_the_hessian(weak_band_op):
    # H^T H <= D up to the accuracy of 15 power iterations (as for operator_norm_sq's scalar
    # step): the largest eigenvalue of D^{-1/2} H^T H D^{-1/2} is at most 1.02, and not far
    # below one (the step is not wasted).
    d = band_metric(weak_band_op, np.float64)
    h = weak_band_op.matrix
    dv = np.repeat(d, SHAPE[1] * SHAPE[2])
    top = np.linalg.eigvalsh((h / np.sqrt(dv)).T @ (h / np.sqrt(dv)))[-1]
    assert 0.9 < top <= 1.02


@pytest.mark.parametrize("exponent", [0.0, 0.5, 1.0])
def test_metric_follows_the_column_norms(weak_band_op, exponent):
    c = band_column_norms_sq(weak_band_op, np.float64)
    d = band_metric(weak_band_op, np.float64, exponent)
    assert d / d.max() == pytest.approx((c / c.max()) ** exponent, rel=1e-9)


def test_band_prox_is_the_per_band_prox():
    # prox in the metric D = diag(d_l) equals, band by band, the TV prox at step 1/d_l: the
    # scaled single call runs the same dual iterations (cold start, then warm).
    rng = np.random.default_rng(0)
    d = np.array([40.0, 3.0, 9.0])
    tau = 0.2
    bm = BandMetric(d, np.float64)
    prior = TVPrior(tau, iters=5)
    per_band = [TVPrior(tau, iters=5) for _ in d]
    for _ in range(3):       # three calls: the warm duals must agree too
        v = rng.standard_normal(SHAPE)
        got = bm.prox(prior, v * (d / d.max())[:, None, None], out=np.empty(SHAPE))
        want = np.stack([p.prox(v[l:l + 1], 1.0 / d[l]) for l, p in enumerate(per_band)])[:, 0]
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)


def test_same_minimum_closer_sooner(weak_band_op):
    # Both metrics minimise the same objective: long runs agree on its minimum.  The band
    # metric's iterates approach the minimiser far sooner, the weak bands no longer held to
    # the strong band's step.
    g = weak_band_op.forward(_truth())
    scalar = fista_tv(weak_band_op, g, iters=5000, tau=0.02, objective=True)
    ref = fista_tv(weak_band_op, g, iters=5000, tau=0.02, objective=True, metric="bands")
    assert ref.info["metric"] == "bands" and scalar.info["metric"] == "scalar"
    assert ref.objective[-1] == pytest.approx(scalar.objective[-1], rel=1e-6)
    xs = ref.x

    def distance(**kw):
        d = []
        fista_tv(weak_band_op, g, iters=200, tau=0.02, callback=lambda it, x, info: d.append(
            np.linalg.norm(x - xs) / np.linalg.norm(xs)), **kw)
        return d[-1]
    assert distance(metric="bands") < 0.01 * distance()


def test_objective_decreases(weak_band_op):
    x = _truth()
    g = weak_band_op.forward(x) + 0.01 * np.random.default_rng(1).standard_normal(
        weak_band_op.oshape)
    res = fista_tv(weak_band_op, g, iters=200, tau=0.02, objective=True, metric="bands")
    h = np.array(res.objective)
    assert h[-1] < 0.3 * h[0]
    # Monotone up to the restarts' one-step rises, which the restart then undoes.
    assert np.all(np.minimum.accumulate(h)[10:] <= h[:-10] + 1e-12)


def test_float32_loop_and_prior_object(weak_band_op):
    g = weak_band_op.forward(_truth()).astype(np.float32)
    res = fista_tv(weak_band_op, g, iters=30, prior=TVPrior(0.02), metric="auto")
    assert res.x.dtype == np.float32 and res.info["metric"] == "bands"
    assert np.isfinite(res.x).all()


def test_auto_falls_back_for_other_priors(weak_band_op):
    g = weak_band_op.forward(_truth())
    nlr = make_prior("subspace-nlr", shape=SHAPE, dtype=np.float64, weight=0.02)
    assert not band_scalable(nlr) and not band_weighted(nlr) and band_scalable(TVPrior(0.1))
    res = fista_tv(weak_band_op, g, iters=2, prior=nlr, metric="auto")
    assert res.info["metric"] == "scalar"
    with pytest.raises(InputError, match="band metric"):
        fista_tv(weak_band_op, g, iters=2, prior=nlr, metric="bands")


class _FixedSubspace:
    """The indicator of span E for a fixed orthonormal E (L x k): its prox, E E^T v, couples
    the bands; taken on the band-weighted cube."""

    band_weighted = True

    def __init__(self, e):
        self.e = e

    def prox(self, v, step, out=None):
        y = np.einsum("lk,mk,mhw->lhw", self.e, self.e, v)
        if out is None:
            return y
        out[...] = y
        return out

    def value(self, x):
        return 0.0

    def reset(self):
        pass


def test_weighted_prox_is_the_metric_projection():
    # The prox of psi(x) = iota(w x in span E) in the metric D is the D-orthogonal projection
    # onto span(w^-1 E): B (B^T D B)^-1 B^T D v, computed here by weighted least squares.
    rng = np.random.default_rng(5)
    d = np.array([0.2, 3.0, 1.1, 0.7])
    e = np.linalg.qr(rng.standard_normal((4, 2)))[0]
    v = rng.standard_normal((4, 3, 2))
    bm = BandMetric(d, np.float64, weighted=True)
    out = bm.prox(_FixedSubspace(e), v / (d.max() / d)[:, None, None], np.empty_like(v))
    b = e / np.sqrt(d / d.max())[:, None]
    sq = np.sqrt(d)[:, None]
    coef = np.linalg.lstsq(sq * b, sq * v.reshape(4, -1), rcond=None)[0]
    np.testing.assert_allclose(out, (b @ coef).reshape(v.shape), rtol=1e-10, atol=1e-12)
    # The scaled (TV) form would be a different map here: the flag matters.
    scaled = BandMetric(d, np.float64).prox(_FixedSubspace(e), v / (d.max() / d)[:, None, None],
                                            np.empty_like(v))
    assert np.abs(scaled - out).max() > 1e-3


def test_subspace_tv_runs_weighted(weak_band_op):
    g = weak_band_op.forward(_truth())
    sub = make_prior("subspace-tv", shape=SHAPE, dtype=np.float64, weight=0.02, rank=2)
    assert band_weighted(sub) and not band_scalable(sub)
    res = fista_tv(weak_band_op, g, iters=40, prior=sub, metric="auto", objective=True)
    assert res.info["metric"] == "bands" and res.info["band_weighted"]
    # The objective the loop records is the data term plus the prior on w x.
    w = np.sqrt(np.array(res.info["band_metric"]) / max(res.info["band_metric"]))
    r = g - weak_band_op.forward(res.x)
    expect = 0.5 * float(np.vdot(r, r)) + sub.value(res.x * w[:, None, None])
    assert res.objective[-1] == pytest.approx(expect, rel=1e-9)
    assert res.objective[-1] < 0.5 * res.objective[0]
    tv = fista_tv(weak_band_op, g, iters=2, prior=TVPrior(0.02), metric="auto")
    assert not tv.info["band_weighted"]


def test_subspace_tv_takes_its_values_from_the_prox(weak_band_op, monkeypatch):
    # The restart test's prior values come from the prox's coefficient images: the new
    # iterate's from the last prox (its own projection, no second one), the previous
    # iterate's, scored again with the new basis from the second iteration on, from the
    # previous prox's coefficients turned into the new basis (no projection either).  The
    # same iterates and objective as with value calls that project the cube.
    from recon.priors import subspace

    g = weak_band_op.forward(_truth())
    calls = []
    project = subspace.project
    monkeypatch.setattr(subspace, "project", lambda e, v: calls.append(1) or project(e, v))

    def run():
        calls.clear()
        sub = make_prior("subspace-tv", shape=SHAPE, dtype=np.float64, weight=0.02, rank=2)
        return fista_tv(weak_band_op, g, iters=30, prior=sub, metric="auto", objective=True)

    fast = run()
    assert len(calls) == 30
    monkeypatch.setattr(subspace.SubspaceTV, "previous_value", lambda self: None)
    half = run()
    assert len(calls) == 30 + 29
    monkeypatch.setattr(subspace.SubspaceTV, "prox_value", lambda self: None)
    slow = run()
    assert len(calls) == 60 + 29
    for res in (half, slow):
        assert fast.iterations == res.iterations
        assert fast.info["restarts"] == res.info["restarts"]
        np.testing.assert_allclose(fast.objective, res.objective, rtol=1e-9)
        np.testing.assert_allclose(fast.x, res.x, rtol=1e-7, atol=1e-9)


def test_bad_options(weak_band_op):
    g = weak_band_op.forward(_truth())
    with pytest.raises(InputError, match="metric must be"):
        fista_tv(weak_band_op, g, iters=2, tau=0.1, metric="diagonal")
    with pytest.raises(InputError, match="exponent"):
        fista_tv(weak_band_op, g, iters=2, tau=0.1, metric="bands", metric_exponent=2.0)
    with pytest.raises(InputError, match="metric_exponent"):
        fista_tv(weak_band_op, g, iters=2, tau=0.1, metric_exponent=0.5)
    with pytest.raises(InputError, match="lipschitz"):
        fista_tv(weak_band_op, g, iters=2, tau=0.1, metric="bands", lipschitz=3.0)
    with pytest.raises(InputError, match="positive"):
        BandMetric([1.0, 0.0, 2.0], np.float64)


def test_matches_the_objective_helper(weak_band_op):
    g = weak_band_op.forward(_truth())
    res = fista_tv(weak_band_op, g, iters=20, tau=0.02, objective=True, metric="bands")
    assert res.objective[-1] == pytest.approx(objective(weak_band_op, g, res.x, tau=0.02),
                                              rel=1e-12)


def test_a_metric_estimated_already_is_taken_as_it_is(weak_band_op, monkeypatch):
    """band_metric= replaces the estimate (no forward/adjoint pair for it) and gives the solve
    that estimating it gives; a solve in the scalar metric, or with an exponent, refuses it."""
    import recon.solvers.band_metric as bmod

    g = weak_band_op.forward(_truth())
    d = band_metric(weak_band_op, np.float64)
    ref = fista_tv(weak_band_op, g, iters=25, tau=0.02, metric="bands")
    assert ref.info["band_metric"] == d.tolist()

    def no_estimate(*a, **k):
        raise AssertionError("the metric was estimated again")

    monkeypatch.setattr(bmod, "band_metric", no_estimate)
    got = fista_tv(weak_band_op, g, iters=25, tau=0.02, metric="auto", band_metric=d)
    assert np.array_equal(got.x, ref.x) and got.info["band_metric"] == d.tolist()
    other = fista_tv(weak_band_op, g, iters=25, tau=0.02, metric="bands", band_metric=2 * d)
    assert not np.allclose(other.x, ref.x)
    nlr = make_prior("subspace-nlr", shape=SHAPE, dtype=np.float64, weight=0.02)
    for kw, match in (({"metric": "scalar"}, "scalar metric"),
                      ({"metric": "auto", "lipschitz": 3.0}, "scalar metric"),
                      ({"metric": "auto", "prior": nlr, "tau": None}, "scalar metric"),
                      ({"metric": "bands", "metric_exponent": 0.5}, "not both"),
                      ({"metric": "bands", "band_metric": d[:2]}, "one value per band"),
                      ({"metric": "bands", "band_metric": -d}, "positive")):
        opts = {"tau": 0.02, "band_metric": d, **kw}
        with pytest.raises(InputError, match=match):
            fista_tv(weak_band_op, g, iters=2, **opts)


def test_two_stages_leave_the_given_metric_to_the_first(weak_band_op):
    """subspace-nlr through solve(): its subspace-tv stage takes the metric given, its
    denoiser stage the scalar step (without the metric, which it would refuse)."""
    from recon.solvers import solve

    g = weak_band_op.forward(_truth()).astype(np.float32)
    nlr = make_prior("subspace-nlr", shape=SHAPE, dtype=np.float32, weight=0.02,
                     solver="fista")
    d = band_metric(weak_band_op, np.float32)
    res = solve("fista-tv", weak_band_op, g, iters=300, tol=1e-2, prior=nlr, metric="auto",
                band_metric=d)
    assert res.info["first_stage"]["iterations"] < 300        # the rule stopped it
    assert res.iterations > res.info["first_stage"]["iterations"]
    assert res.info["metric"] == "scalar"
