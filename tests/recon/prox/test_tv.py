"""Tests of the spatial TV norms and the Chambolle TV prox (recon.prox.tv)."""

import numpy as np
import pytest
from skimage.restoration import denoise_tv_chambolle

from recon.errors import InputError
from recon.prox import TVProx, divergence, gradient, prox_tv, tv_norm, tv_norm_per_band


def _cube(seed=0, shape=(5, 24, 20), dtype=np.float64):
    rng = np.random.default_rng(seed)
    x = np.zeros(shape)
    x[:, 4:14, 3:11] = 1.0
    x[:, 10:20, 9:17] += 0.5
    x *= rng.uniform(0.5, 1.5, (shape[0], 1, 1))
    return (x + 0.1 * rng.standard_normal(shape)).astype(dtype)


def _primal(x, v, lam, isotropic):
    d = (x - v).astype(np.float64)
    return 0.5 * np.vdot(d, d) + lam * tv_norm(x, isotropic)


def test_tv_norm_definitions():
    x = _cube()
    dy = np.diff(x, axis=1)
    dx = np.diff(x, axis=2)
    aniso = np.abs(dy).sum() + np.abs(dx).sum()  # paper Eq. 7
    assert tv_norm(x, isotropic=False) == pytest.approx(aniso, rel=1e-12)
    gy = np.zeros_like(x); gy[:, :-1] = dy
    gx = np.zeros_like(x); gx[:, :, :-1] = dx
    assert tv_norm(x) == pytest.approx(np.sqrt(gy**2 + gx**2).sum(), rel=1e-12)
    per = tv_norm_per_band(x)
    assert per.shape == (x.shape[0],)
    assert per.sum() == pytest.approx(tv_norm(x))
    # Spatial only: a cube constant in space but varying across bands has zero TV.
    flat = np.ones((4, 6, 7)) * np.arange(4)[:, None, None]
    assert tv_norm(flat) == 0 and tv_norm(flat, isotropic=False) == 0


def test_divergence_is_minus_adjoint_of_gradient():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((3, 9, 11))
    p = rng.standard_normal((2, 3, 9, 11))
    lhs = np.vdot(gradient(x), p)
    rhs = -np.vdot(x, divergence(p))
    assert abs(lhs - rhs) <= 1e-12 * abs(lhs)


@pytest.mark.parametrize("n_iter", [1, 4, 15])
@pytest.mark.parametrize("threads", [1, 2])
def test_matches_skimage_iterate_by_iterate(n_iter, threads):
    # skimage's n+1 iterations evaluate the primal after n dual updates.
    v = _cube(2)
    ours = prox_tv(v, 0.15, n_iter, threads=threads)
    ref = denoise_tv_chambolle(np.moveaxis(v, 0, -1), weight=0.15, eps=0.0,
                               max_num_iter=n_iter + 1, channel_axis=-1)
    np.testing.assert_allclose(ours, np.moveaxis(ref, -1, 0), atol=1e-12)


def test_converged_prox_matches_converged_skimage_float32():
    v = _cube(3, dtype=np.float32)
    ours = prox_tv(v, 0.2, 400)
    assert ours.dtype == np.float32
    ref = denoise_tv_chambolle(np.moveaxis(v, 0, -1), weight=0.2, eps=1e-9,
                               max_num_iter=400, channel_axis=-1)
    np.testing.assert_allclose(ours, np.moveaxis(ref, -1, 0), atol=2e-3)


@pytest.mark.parametrize("isotropic", [True, False])
def test_prox_is_optimal(isotropic):
    v, lam = _cube(4), 0.3
    x = prox_tv(v, lam, 600, isotropic=isotropic)
    best = _primal(x, v, lam, isotropic)
    rng = np.random.default_rng(5)
    for scale in (1e-1, 1e-2, 1e-3):
        for _ in range(5):
            y = x + scale * rng.standard_normal(x.shape)
            assert _primal(y, v, lam, isotropic) > best
    # And it beats the obvious candidates.
    assert best < _primal(v, v, lam, isotropic)
    assert best < _primal(np.broadcast_to(v.mean(axis=(1, 2), keepdims=True), v.shape).copy(),
                          v, lam, isotropic)


@pytest.mark.parametrize("isotropic", [True, False])
def test_duality_gap_closes(isotropic):
    # Dual: max_p  1/2|v|^2 - 1/2|v - lam div p|^2 over the unit ball; gap -> 0 at the optimum.
    v, lam = _cube(6), 0.25
    prox = TVProx(v.shape, np.float64, isotropic)
    gaps = []
    for n in (10, 100, 1000):
        x = prox(v, lam, n, warm=False)
        dual = 0.5 * np.vdot(v, v) - 0.5 * np.vdot(x, x)
        gaps.append(_primal(x, v, lam, isotropic) - dual)
        if isotropic:
            assert np.sqrt((prox.dual**2).sum(0)).max() <= 1 + 1e-12
        else:
            assert np.abs(prox.dual).max() <= 1 + 1e-12
    assert all(gap >= -1e-9 for gap in gaps)
    assert gaps[2] < 0.05 * gaps[0]
    assert gaps[2] < 1e-3 * _primal(v, v, lam, isotropic)


def test_warm_start_continues_cold_iterations():
    v = _cube(7)
    prox = TVProx(v.shape, np.float64)
    prox(v, 0.2, 3, warm=False)
    warm = prox(v, 0.2, 4, warm=True)
    cold = prox_tv(v, 0.2, 7)
    np.testing.assert_allclose(warm, cold, atol=1e-12)
    # The dual= argument of prox_tv is updated in place.
    dual = np.zeros((2,) + v.shape)
    prox_tv(v, 0.2, 3, dual=dual)
    np.testing.assert_allclose(prox_tv(v, 0.2, 4, dual=dual), cold, atol=1e-12)


def test_warm_dual_tracks_a_moving_input():
    # Small changes of v: 2 warm iterations stay closer to the exact prox than 2 cold ones.
    v = _cube(8)
    rng = np.random.default_rng(9)
    prox = TVProx(v.shape, np.float64)
    prox(v, 0.2, 50)
    v2 = v + 0.01 * rng.standard_normal(v.shape)
    exact = prox_tv(v2, 0.2, 2000)
    warm = prox(v2, 0.2, 2)
    cold = prox_tv(v2, 0.2, 2)
    assert np.linalg.norm(warm - exact) < 0.5 * np.linalg.norm(cold - exact)


def test_out_may_alias_input_and_zero_weight():
    v = _cube(10, dtype=np.float32)
    ref = prox_tv(v, 0.1, 5)
    w = v.copy()
    prox_tv(w, 0.1, 5, out=w)
    np.testing.assert_array_equal(w, ref)
    np.testing.assert_array_equal(prox_tv(v, 0.0, 5), v)


def test_bad_inputs():
    with pytest.raises(InputError):
        prox_tv(np.zeros((4, 4)), 0.1)
    with pytest.raises(InputError):
        prox_tv(np.zeros((2, 4, 4)), -1.0)
    with pytest.raises(InputError):
        TVProx((2, 4, 4))(np.zeros((2, 4, 5)), 0.1)
    with pytest.raises(InputError):
        prox_tv(np.zeros((2, 4, 4)), 0.1, dual=np.zeros((2, 2, 4, 5)))


@pytest.mark.parametrize("shape", [(3, 7, 5), (4, 1, 6), (2, 9, 1), (5, 13, 11)])
@pytest.mark.parametrize("strip_bytes", [1, 40, 1 << 18])
@pytest.mark.parametrize("threads", [1, 3])
def test_tv_norm_strips_straddling_bands(monkeypatch, shape, strip_bytes, threads):
    # Tiny strips cross band edges (the flat row after a band's last row is the next band's
    # first): the vertical difference there must not count.
    import recon.prox.tv as tvmod

    monkeypatch.setattr(tvmod, "_TV_STRIP_BYTES", strip_bytes)
    x = np.random.default_rng(4).standard_normal(shape)
    gy = np.zeros_like(x); gy[:, :-1] = np.diff(x, axis=1)
    gx = np.zeros_like(x); gx[:, :, :-1] = np.diff(x, axis=2)
    np.testing.assert_allclose(tv_norm_per_band(x, threads=threads),
                               np.sqrt(gy**2 + gx**2).sum(axis=(1, 2)), rtol=1e-12)
    np.testing.assert_allclose(tv_norm_per_band(x, isotropic=False, threads=threads),
                               (np.abs(gy) + np.abs(gx)).sum(axis=(1, 2)), rtol=1e-12)


def test_tv_norm_float32_accumulates_in_float64():
    x = np.random.default_rng(5).random((3, 200, 300), dtype=np.float32)
    ref = tv_norm(x.astype(np.float64))
    assert tv_norm(x) == pytest.approx(ref, rel=1e-6)


@pytest.mark.parametrize("n,threads,min_span", [(0, 2, 1), (1, 4, 1), (10, 3, 1), (1000, 4, 7),
                                                (5, 2, 100)])
def test_parallel_spans_cover_exactly_once(n, threads, min_span):
    from recon.prox.tv import parallel_spans

    hits = np.zeros(n, dtype=int)
    spans = []

    def fn(a, b):
        spans.append((a, b))
        hits[a:b] += 1

    parallel_spans(fn, n, threads, min_span)
    assert np.all(hits == 1)
    assert all(b - a >= min(min_span, n) for a, b in spans)
    assert len(spans) <= max(1, threads)
