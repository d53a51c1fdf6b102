"""The TV prior (recon.priors.tv): its prox against the Chambolle prox and skimage, its value
against a NumPy TV, the fused gradient step, the state it carries, and bad input."""

import numpy as np
import pytest
from skimage.restoration import denoise_tv_chambolle

from recon.errors import InputError
from recon.operators import standard_cassi
from recon.priors import Prior, TVPrior
from recon.priors.base import PriorBase
from recon.priors.tv import DEFAULT_WEIGHT, check_weight, default_weight
from recon.prox import TVProx, prox_tv


def _cube(seed=0, shape=(4, 20, 18), dtype=np.float64):
    rng = np.random.default_rng(seed)
    x = np.zeros(shape)
    x[:, 3:12, 2:10] = 1.0
    x[:, 9:17, 8:15] += 0.5
    return (x + 0.1 * rng.standard_normal(shape)).astype(dtype)


def _numpy_tv(x, isotropic):
    """Forward differences, Neumann boundary, summed over bands (the definition)."""
    gy = np.zeros_like(x, dtype=np.float64)
    gx = np.zeros_like(x, dtype=np.float64)
    gy[:, :-1] = np.diff(x, axis=1)
    gx[:, :, :-1] = np.diff(x, axis=2)
    return float(np.sqrt(gy**2 + gx**2).sum() if isotropic else (np.abs(gy) + np.abs(gx)).sum())


def test_is_a_prior():
    assert isinstance(TVPrior(0.1), Prior)
    assert isinstance(TVPrior(0.1), PriorBase)


@pytest.mark.parametrize("isotropic", [True, False])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_prox_is_the_chambolle_prox_of_weight_times_step(isotropic, dtype):
    v = _cube(1, dtype=dtype)
    prior = TVPrior(0.3, iters=6, isotropic=isotropic)
    got = prior.prox(v, 0.5)
    # Cold first call: the Chambolle prox of weight 0.3 * 0.5 after 6 dual iterations.
    ref = prox_tv(v, 0.3 * 0.5, 6, isotropic=isotropic)
    assert got.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(got, ref)
    # Warm second call: continues from the dual the first left, as a TVProx does.
    tv = TVProx(v.shape, dtype, isotropic)
    tv(v, 0.15, 6)
    np.testing.assert_array_equal(prior.prox(v * 1.1, 0.5), tv(v * 1.1, 0.15, 6, warm=True))
    # reset(): a cold start again.
    prior.reset()
    np.testing.assert_array_equal(prior.prox(v, 0.5), ref)


def test_rescaled_prox_is_the_prox_times_a_factor_per_band():
    # TV scales as its prox writes; the protocol's default (prox, then a pass) and a bare
    # prior's give the same bits.
    from recon.priors.base import PriorBase, rescaled_prox

    rng = np.random.default_rng(6)
    v = rng.standard_normal((4, 12, 10)).astype(np.float32)
    r = np.array([1.0, 2.5, 1.25, 7.0], np.float32)
    fused, default, bare = (TVPrior(0.2, v.shape) for _ in range(3))
    for _ in range(3):                                   # warm duals stay in step too
        a = fused.rescaled_prox(v, 0.5, r)
        b = PriorBase.rescaled_prox(default, v, 0.5, r)

        class Bare:
            def prox(self, x, step, out=None):
                return bare.prox(x, step, out=out)
        c = rescaled_prox(Bare(), v, 0.5, r)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    want = TVPrior(0.2, v.shape).prox(v, 0.5) * r[:, None, None]
    np.testing.assert_array_equal(TVPrior(0.2, v.shape).rescaled_prox(v, 0.5, r), want)


def test_cold_prior_without_warm_start_repeats_itself():
    v = _cube(2)
    prior = TVPrior(0.2, iters=4, warm=False)
    a = prior.prox(v, 1.0)
    b = prior.prox(v, 1.0)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, prox_tv(v, 0.2, 4))


def test_converged_prox_matches_skimage():
    # The prox's definition, argmin 1/2|x - v|^2 + s tau TV(x), solved independently.
    v = _cube(3)
    prior = TVPrior(0.25, iters=300, warm=True)
    got = prior.prox(v, 0.4)
    ref = denoise_tv_chambolle(np.moveaxis(v, 0, -1), weight=0.1, eps=0.0, max_num_iter=301,
                               channel_axis=-1)
    np.testing.assert_allclose(got, np.moveaxis(ref, -1, 0), atol=1e-10)


@pytest.mark.parametrize("isotropic", [True, False])
def test_value_is_weight_times_tv(isotropic):
    x = _cube(4)
    assert TVPrior(0.7, isotropic=isotropic).value(x) == pytest.approx(
        0.7 * _numpy_tv(x, isotropic), rel=1e-12)
    assert TVPrior(0.0).value(x) == 0.0


def test_zero_weight_prox_is_identity():
    v = _cube(5)
    np.testing.assert_array_equal(TVPrior(0.0).prox(v, 3.0), v)


def test_prox_in_place():
    v = _cube(6, dtype=np.float32)
    ref = TVPrior(0.2).prox(v, 1.0)
    w = v.copy()
    out = TVPrior(0.2).prox(w, 1.0, out=w)
    assert out is w
    np.testing.assert_array_equal(w, ref)


def test_gradient_prox_is_the_gradient_step_then_the_prox():
    rng = np.random.default_rng(7)
    op = standard_cassi((rng.random((20, 18)) > 0.5).astype(np.float32), 1, 4)
    base = _cube(7, dtype=np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    fused = TVPrior(0.2, iters=2).gradient_prox(op, y, base, 0.5, scale=0.3)
    # The generic form: adjoint_add, then the prox.
    plain = PriorBase.gradient_prox(TVPrior(0.2, iters=2), op, y, base, 0.5, scale=0.3)
    np.testing.assert_allclose(fused, plain, rtol=0, atol=1e-5)
    ref = prox_tv(base + 0.3 * op.adjoint(y), 0.1, 2)
    np.testing.assert_allclose(fused, ref, rtol=0, atol=1e-5)


def test_combine_value_matches_combination_and_value():
    rng = np.random.default_rng(8)
    u, v, w = (rng.standard_normal((3, 17, 19)) for _ in range(3))
    out = np.empty_like(u)
    prior = TVPrior(0.4)
    val = prior.combine_value(-0.5, u, 0.25, v, 1.25, w, out)
    ref = -0.5 * u + 0.25 * v + 1.25 * w
    np.testing.assert_allclose(out, ref, atol=1e-12)
    assert val == pytest.approx(0.4 * _numpy_tv(ref, True), rel=1e-10)


def test_refine_continues_the_prox():
    v = _cube(9)
    prior = TVPrior(0.2, iters=2)
    out = prior.prox(v, 1.0)
    assert prior.refine(v, 1.0, out) == 2
    np.testing.assert_allclose(out, prox_tv(v, 0.2, 4), atol=1e-12)


def test_state_round_trip():
    v = _cube(10)
    a = TVPrior(0.2, iters=2)
    a.prox(v, 1.0)
    st = a.state()
    b = TVPrior(0.2, iters=2)
    b.load_state(st)
    np.testing.assert_array_equal(a.prox(v, 1.0), b.prox(v, 1.0))
    assert TVPrior(0.1).state() == {}
    with pytest.raises(InputError, match="dual"):
        TVPrior(0.1, shape=v.shape).load_state({"dual": np.zeros((2, 1, 2, 3))})


def test_new_shape_starts_cold():
    prior = TVPrior(0.2, iters=2)
    prior.prox(_cube(11), 1.0)
    small = _cube(12, shape=(2, 8, 9))
    np.testing.assert_array_equal(prior.prox(small, 1.0), prox_tv(small, 0.2, 2))


def test_defaults_and_range_in_one_place():
    assert default_weight("fista-tv") == DEFAULT_WEIGHT["fista"]
    assert default_weight("gap-tv") == DEFAULT_WEIGHT["gap"]
    assert default_weight("twist") == DEFAULT_WEIGHT["twist"]
    with pytest.raises(InputError, match="no default TV weight"):
        default_weight("nope")
    assert check_weight(0) == 0.0
    for bad in (-1e-9, float("nan"), float("inf"), "x", None):
        with pytest.raises(InputError, match="--tau"):
            check_weight(bad, "--tau")


@pytest.mark.parametrize("kw", [{"weight": -0.1}, {"weight": float("nan")},
                                {"weight": 0.1, "iters": 0}, {"weight": 0.1, "iters": 1.5},
                                {"weight": 0.1, "iters": True}])
def test_bad_parameters(kw):
    with pytest.raises(InputError):
        TVPrior(**kw)


def test_bad_input():
    with pytest.raises(InputError, match="step"):
        TVPrior(0.1).prox(_cube(), -1.0)
    with pytest.raises(InputError, match="step"):
        TVPrior(0.1).prox(_cube(), float("nan"))
    with pytest.raises(InputError, match=r"\(L, H, W\)"):
        TVPrior(0.1).prox(np.zeros((4, 5)), 1.0)
