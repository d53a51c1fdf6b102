"""The temporal term (recon.temporal): its prox, the prior it makes around a spatial one, and
GAP with it carrying its state from frame to frame."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import standard_cassi
from recon.priors import TVPrior
from recon.solvers import fista_tv, gap_tv
from recon.temporal import TemporalPrior, gap_tv_temporal, temporal_prox


def _cube(seed=0, shape=(3, 12, 10)):
    rng = np.random.default_rng(seed)
    x = np.full(shape, 0.3)
    x[:, 3:8, 2:7] = 0.9
    return (x + 0.05 * rng.standard_normal(shape)).astype(np.float32)


def test_temporal_prox_is_a_soft_threshold_towards_the_reference():
    v = np.array([[[0.0, 0.5, 1.0, -1.0]]])
    r = np.array([[[0.2, 0.2, 0.2, 0.2]]])
    np.testing.assert_allclose(temporal_prox(v, r, 0.3), [[[0.2, 0.2, 0.7, -0.7]]])


def test_temporal_prior_is_the_spatial_prox_then_the_threshold():
    v, ref = _cube(1), _cube(2)
    got = TemporalPrior(TVPrior(0.1), ref, 0.05).prox(v, 0.5)
    want = temporal_prox(TVPrior(0.1).prox(v, 0.5), ref, 0.025)
    np.testing.assert_array_equal(got, want)
    p = TemporalPrior(TVPrior(0.1), ref, 0.05)
    x = _cube(3)
    assert p.value(x) == pytest.approx(TVPrior(0.1).value(x)
                                       + 0.05 * np.abs(x - ref).astype(np.float64).sum(),
                                       rel=1e-6)


def test_temporal_prior_reports_the_spatial_priors_state_change():
    from recon.priors.subspace import SubspaceTV

    ref = _cube(2)
    assert TemporalPrior(TVPrior(0.1), ref, 0.05).state_change() is None
    p = TemporalPrior(SubspaceTV(0.1, rank=2), ref, 0.05)
    p.prox(_cube(1), 0.5)
    p.prox(_cube(3), 0.5)
    assert p.state_change() is not None
    assert p.state_change() == p.spatial.state_change()


def test_temporal_prior_hands_on_the_spatial_priors_stages():
    """A spatial prior of two stages keeps them inside the temporal prior: the first stage
    with the temporal term around it, not the denoiser from the first call."""
    from recon.priors.nonlocal_lowrank import SubspaceNLR
    from recon.priors.subspace import SubspaceTV

    ref = _cube(2)
    assert TemporalPrior(TVPrior(0.1), ref, 0.05).stages() is None
    assert TemporalPrior(SubspaceNLR(0.1, warmup=5), ref, 0.05).stages() is None
    first, n = TemporalPrior(SubspaceNLR(0.1, rank=2, warmup="rule", denoise_iters=9), ref,
                             0.05).stages()
    assert n == 9 and isinstance(first, TemporalPrior) and first.mu == 0.05
    assert type(first.spatial) is SubspaceTV and first.ref is ref


def test_temporal_prior_goes_with_any_solver():
    rng = np.random.default_rng(4)
    op = standard_cassi((rng.random((12, 10)) > 0.5).astype(np.float32), 1, 3)
    truth = _cube(5)
    g = op.forward(truth)
    # A huge temporal weight holds the solution at the reference.
    res = fista_tv(op, g, iters=30, prior=TemporalPrior(TVPrior(0.01), truth, 1e3))
    np.testing.assert_allclose(res.x, truth, atol=1e-6)
    assert res.info["temporal_mu"] == 1e3


def test_gap_tv_temporal_is_gap_with_the_temporal_prior():
    rng = np.random.default_rng(6)
    op = standard_cassi((rng.random((12, 10)) > 0.5).astype(np.float32), 1, 3)
    ref = _cube(7)
    g = op.forward(_cube(8))
    r1 = gap_tv_temporal(op, g, ref=ref, mu=0.01, iters=8, tau=0.1)
    same = gap_tv(op, g, iters=8, prior=TemporalPrior(TVPrior(0.1), ref, 0.01), x0=ref,
                  keep_state=True)
    np.testing.assert_array_equal(r1.x, same.x)
    # The state carries the dual and the accumulated residual to the next frame.
    r2 = gap_tv_temporal(op, g, ref=r1.x, mu=0.01, iters=8, tau=0.1, state=r1.info["state"])
    prior = TemporalPrior(TVPrior(0.1), r1.x, 0.01)
    again = gap_tv(op, g, iters=8, prior=prior, x0=r1.x, state=r1.info["state"])
    np.testing.assert_array_equal(r2.x, again.x)
    cold = gap_tv_temporal(op, g, ref=r1.x, mu=0.01, iters=8, tau=0.1)
    assert not np.array_equal(cold.x, r2.x)


def test_bad_input():
    ref = _cube()
    with pytest.raises(InputError, match="mu"):
        TemporalPrior(TVPrior(0.1), ref, -1.0)
    with pytest.raises(InputError, match="NaN"):
        TemporalPrior(TVPrior(0.1), np.full_like(ref, np.nan), 0.1)
    with pytest.raises(InputError, match="recon prior"):
        TemporalPrior(object(), ref, 0.1)
    rng = np.random.default_rng(9)
    op = standard_cassi((rng.random((12, 10)) > 0.5).astype(np.float32), 1, 3)
    g = op.forward(ref)
    with pytest.raises(InputError, match="offset"):
        gap_tv_temporal(op, g, ref=ref, mu=0.1, state={"offset": np.zeros(3)})
    with pytest.raises(InputError, match="dual"):
        gap_tv_temporal(op, g, ref=ref, mu=0.1, state={"dual": np.zeros((2, 1, 1, 1))})
