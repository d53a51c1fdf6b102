"""Every fused kernel against the NumPy path it replaces (float32, tight tolerances).

The NumPy path is reached through the same public calls inside ``kernels.numpy_only()``, so
these tests check the dispatch as well as the kernels.  The kernels exist in float32 only
(float64 runs take the NumPy path), so every comparison here is in float32.  Sizes are small
(the kernels compile once and are cached on disk; the sizes do not change that cost) but odd,
with single rows and columns, so that every edge branch runs.
"""

import numpy as np
import pytest

from kernel_checks import (RTOL32, assert_operator_matches_numpy, permutation_cassi, rel,
                           warped_cassi)
from recon import kernels
from recon.errors import InputError
from recon.operators import dot_test
from recon.prox import TVProx, tv_norm_per_band
from recon.solvers import solve
from recon.solvers.band_metric import BandMetric
from recon.solvers.fista_tv import _extrapolate, _momentum_pass, _restart_dot
from recon.priors import TVPrior
from recon.priors.base import linear_combination as _combine

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


# -- the switch ----------------------------------------------------------------------------


def test_switches(monkeypatch):
    assert kernels.enabled()
    with kernels.numpy_only():
        assert not kernels.enabled()
        with kernels.numpy_only():
            assert not kernels.enabled()
        assert not kernels.enabled()
    assert kernels.enabled()
    monkeypatch.setenv("KALEIDOSPEC_KERNELS", "numpy")
    assert not kernels.enabled()


# -- TV ------------------------------------------------------------------------------------

SHAPES = [(3, 7, 9), (2, 1, 6), (2, 5, 1), (1, 1, 1), (4, 16, 13)]


def _prox_pair(shape, dtype, isotropic, n_iter, warm, seed, alias=False):
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(shape).astype(dtype)
    dual = rng.uniform(-0.7, 0.7, (2,) + shape).astype(dtype)
    res = []
    for fast in (True, False):
        prox = TVProx(shape, dtype, isotropic, threads=2)
        prox.dual[:] = dual
        vin = v.copy()
        with kernels.numpy_only() if not fast else _nothing():
            x = prox(vin, 0.3, n_iter, warm=warm, out=vin if alias else None)
        res.append((x, prox.dual.copy()))
    return res


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("isotropic", [True, False])
@pytest.mark.parametrize("n_iter", [0, 1, 2, 5])
def test_chambolle_prox_matches_numpy(shape, isotropic, n_iter):
    (x, p), (xr, pr) = _prox_pair(shape, np.float32, isotropic, n_iter, True, 1)
    assert x.dtype == np.float32
    assert rel(x, xr) < RTOL32 * (1 + n_iter)
    assert rel(p, pr) < RTOL32 * (1 + n_iter)


@pytest.mark.parametrize("isotropic", [True, False])
def test_chambolle_prox_cold_and_in_place(isotropic):
    (x, p), (xr, pr) = _prox_pair((3, 11, 8), np.float32, isotropic, 4, False, 2, alias=True)
    assert rel(x, xr) < 5 * RTOL32 and rel(p, pr) < 5 * RTOL32


@pytest.mark.parametrize("shape", [(3, 7, 9), (2, 1, 6), (4, 16, 13)])
@pytest.mark.parametrize("alias", [False, True])
@pytest.mark.parametrize("n_iter", [0, 2])
def test_chambolle_prox_scales_its_result_per_band(shape, alias, n_iter):
    # out_scale scales each row as the kernel writes it: the bits of the prox followed by a
    # pass that scales it (what FISTA's band metric would otherwise do on its own); the NumPy
    # path scales after its prox, to the kernel's tolerance.
    rng = np.random.default_rng(4)
    v = rng.standard_normal(shape).astype(np.float32)
    dual = rng.uniform(-0.7, 0.7, (2,) + shape).astype(np.float32)
    r = (1 + 4 * rng.random(shape[0])).astype(np.float32)
    plain, scaled, ref = (TVProx(shape, np.float32, threads=2) for _ in range(3))
    for prox in (plain, scaled, ref):
        prox.dual[:] = dual
    want = plain(v, 0.3, n_iter)
    want *= r[:, None, None]
    vin = v.copy()
    got = scaled(vin, 0.3, n_iter, out=vin if alias else None, out_scale=r)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(scaled.dual, plain.dual)
    with kernels.numpy_only():
        numpy = ref(v, 0.3, n_iter, out_scale=r)
    assert rel(numpy, want) < RTOL32 * (1 + n_iter)
    for bad in (r[:-1], np.full(shape[0], np.nan, np.float32)):
        with pytest.raises(InputError, match="out_scale"):
            scaled(v, 0.3, n_iter, out_scale=bad)


def test_kernels_are_float32_only():
    # float64 (precision checks) takes the NumPy path; the kernels exist in float32 only.
    assert kernels.usable(np.zeros(2, np.float32))
    assert not kernels.usable(np.zeros(2, np.float32), np.zeros(2))


def test_chambolle_prox_many_iterations_converge_alike():
    # 200 iterations in one wavefront pass against 200 NumPy iterations: rounding does not
    # build up into a different answer.
    (x, _), (xr, _) = _prox_pair((2, 20, 17), np.float32, True, 200, False, 3)
    assert rel(x, xr) < 1e-5


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("isotropic", [True, False])
def test_tv_norm_matches_numpy(shape, isotropic):
    x = np.random.default_rng(4).standard_normal(shape).astype(np.float32)
    fast = tv_norm_per_band(x, isotropic)
    with kernels.numpy_only():
        ref = tv_norm_per_band(x, isotropic)
    assert fast.dtype == np.float64
    np.testing.assert_allclose(fast, ref, rtol=RTOL32, atol=1e-6)


# -- CASSI operators -------------------------------------------------------------------------


_RNG = np.random.default_rng(5)
OPS = {**permutation_cassi(_RNG), "with-warped-view": warped_cassi(_RNG)}


@pytest.mark.parametrize("name", sorted(OPS))
def test_cassi_forward_and_adjoint_match_numpy(name):
    assert_operator_matches_numpy(OPS[name], 6)


@pytest.mark.parametrize("name", sorted(OPS))
def test_cassi_kernels_have_exact_adjoints(name):
    # In float32, so that the kernels run: the mismatch is float32 rounding of the sums.
    assert dot_test(OPS[name], np.random.default_rng(7), dtype=np.float32) < 1e-6


@pytest.mark.parametrize("name", sorted(OPS))
@pytest.mark.parametrize("in_place", [False, True])
def test_adjoint_add_is_base_plus_scaled_adjoint(name, in_place):
    op = OPS[name]
    rng = np.random.default_rng(8)
    base = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    want = base + np.float32(0.37) * op.adjoint(y)
    b = base.copy()
    got = op.adjoint_add(y, b, 0.37, out=b if in_place else None)
    assert got.dtype == np.float32 and (got is b) == in_place
    assert rel(got, want) < RTOL32
    with kernels.numpy_only():
        ref = op.adjoint_add(y, base, 0.37)
    assert rel(got, ref) < RTOL32
    # The band metric's base weights: the weighted base, then the same gradient step.
    q = np.linspace(0.2, 1.0, op.ishape[0]).astype(np.float32)
    got = op.adjoint_add(y, base.copy(), 0.37, base_weights=q)
    assert rel(got, q[:, None, None] * base + np.float32(0.37) * op.adjoint(y)) < RTOL32


# -- vector updates --------------------------------------------------------------------------


def test_vector_updates_match_numpy():
    rng = np.random.default_rng(9)
    u, v, w = (rng.standard_normal((3, 37, 41)).astype(np.float32) for _ in range(3))
    out, ref = np.empty_like(u), np.empty_like(u)
    _combine(-0.67, u, 0.36, v, 3.3, w, out)
    with kernels.numpy_only():
        _combine(-0.67, u, 0.36, v, 3.3, w, ref)
    assert rel(out, ref) < RTOL32
    _extrapolate(u, v, 0.8, out, None)
    with kernels.numpy_only():
        _extrapolate(u, v, 0.8, ref, None)
    assert rel(out, ref) < RTOL32
    # Longer than one block of the kernel, so that several partial sums are added.
    a, b, c = (rng.standard_normal(100_003).astype(np.float32) for _ in range(3))
    d = _restart_dot(a, b, c, np.empty_like(a), None)
    with kernels.numpy_only():
        d_ref = _restart_dot(a, b, c, np.empty_like(a), None)
    assert d == pytest.approx(d_ref, rel=1e-5)


@pytest.mark.parametrize("metric", [None, (0.3, 2.0, 1.1)])
@pytest.mark.parametrize("shape", [(3, 37, 41), (3, 211, 317)])
def test_momentum_pass_matches_numpy(metric, shape):
    # FISTA's fused pass (the restart test's inner product, the momentum step, the relative
    # change) against the three NumPy steps it replaces and against the plain expressions in
    # float64, scalar and band metric; the larger shape has several blocks a band.
    rng = np.random.default_rng(21)
    f, step, z0 = (rng.standard_normal(shape).astype(np.float32) for _ in range(3))
    f_prev = f + np.float32(0.1) * step
    bm = None if metric is None else BandMetric(metric, np.float32)
    z, z_ref = z0.copy(), z0.copy()
    dot, change = _momentum_pass(z, f, f_prev, 0.7, bm, None, np.empty_like(f), True)
    with kernels.numpy_only():
        dot_ref, change_ref = _momentum_pass(z_ref, f, f_prev, 0.7, bm, None,
                                             np.empty_like(f), True)
    assert rel(z, z_ref) < RTOL32
    f64, p64, z64 = (a.astype(np.float64) for a in (f, f_prev, z0))
    w = np.ones(shape[0]) if metric is None else np.asarray(metric)
    want = sum(wl * np.vdot(zl - fl, fl - pl) for wl, zl, fl, pl in zip(w, z64, f64, p64))
    # The inner product cancels (terms of either sign): its error is relative to the terms'.
    scale = sum(wl * np.abs((zl - fl) * (fl - pl)).sum() for wl, zl, fl, pl
                in zip(w, z64, f64, p64))
    assert abs(dot - want) < 1e-7 * scale and abs(dot_ref - want) < 1e-6 * scale
    assert change == pytest.approx(change_ref, rel=1e-5)
    assert change == pytest.approx(np.linalg.norm(f64 - p64) / np.linalg.norm(p64), rel=1e-6)
    assert rel(z, (f64 + 0.7 * (f64 - p64)).astype(np.float32)) < RTOL32
    # Without the change asked for it is left out; a zero momentum makes z = f.
    assert _momentum_pass(z, f, f_prev, 0.0, bm, None, np.empty_like(f), False)[1] is None
    assert np.array_equal(z, f)


@pytest.mark.parametrize("isotropic", [True, False])
@pytest.mark.parametrize("shape", [(3, 37, 41), (2, 1, 9), (2, 6, 1)])
def test_combine_with_tv_matches_numpy(isotropic, shape):
    rng = np.random.default_rng(12)
    u, v, w = (rng.standard_normal(shape).astype(np.float32) for _ in range(3))
    out, ref = np.empty_like(u), np.empty_like(u)
    tv = TVPrior(1.0, isotropic=isotropic).combine_value(-0.67, u, 0.36, v, 3.3, w, out)
    with kernels.numpy_only():
        tv_ref = TVPrior(1.0, isotropic=isotropic).combine_value(-0.67, u, 0.36, v, 3.3, w,
                                                                  ref)
    assert rel(out, ref) < RTOL32
    assert tv == pytest.approx(tv_ref, rel=RTOL32)


# -- threads and whole solves ----------------------------------------------------------------


def test_threads_follow_the_cpus_the_process_may_use(monkeypatch):
    import os

    import numba

    for cpus in ({0}, {0, 1, 2}):
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid, c=cpus: set(c), raising=False)
        assert kernels.cores() == len(cpus)
        with kernels.threads():
            assert numba.get_num_threads() == min(len(cpus), numba.config.NUMBA_NUM_THREADS)
        with kernels.threads(1):
            assert numba.get_num_threads() == 1


def test_kernels_do_not_depend_on_threads():
    op = OPS["kaleido9-sub"]
    rng = np.random.default_rng(10)
    x = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    outs = []
    for n in (1, 2, 3):
        with kernels.threads(n):
            prox = TVProx(op.ishape)
            outs.append((op.forward(x), op.adjoint(y), prox(x, 0.2, 3), tv_norm_per_band(x)))
    for other in outs[1:]:
        for a, b in zip(outs[0], other):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("name", ["gap-tv", "twist", "fista-tv"])
def test_solvers_agree_with_the_numpy_path(name):
    op = OPS["kaleido9-sub"]
    rng = np.random.default_rng(11)
    truth = rng.random(op.ishape).astype(np.float32)
    g = op.forward(truth)
    fast = solve(name, op, g, iters=20, tau=0.05)
    with kernels.numpy_only():
        ref = solve(name, op, g, iters=20, tau=0.05)
    assert fast.iterations == ref.iterations
    # 20 iterations of a nonlinear map amplify roundings a little, no more.
    assert rel(fast.x, ref.x) < 1e-4


def test_solves_from_several_threads_at_once():
    # Kernels launched from two Python threads at the same time (a Dask worker's threads)
    # give what they give one after the other.
    from concurrent.futures import ThreadPoolExecutor

    op = OPS["kaleido9-sub"]
    rng = np.random.default_rng(13)
    gs = [op.forward(rng.random(op.ishape).astype(np.float32)) for _ in range(4)]
    alone = [solve("twist", op, g, iters=15, tau=0.05).x for g in gs]
    with ThreadPoolExecutor(2) as ex:
        together = list(ex.map(lambda g: solve("twist", op, g, iters=15, tau=0.05).x, gs))
    for a, b in zip(alone, together):
        assert np.array_equal(a, b)


_CHILD = r"""
import numpy as np
from concurrent.futures import ThreadPoolExecutor
from recon.operators import kaleidoscope_cassi
from recon.solvers import solve
rng = np.random.default_rng(0)
op = kaleidoscope_cassi(rng.random((3, 16, 18)).astype(np.float32), 0.7 * np.arange(5), 3)
gs = [op.forward(rng.random(op.ishape).astype(np.float32)) for _ in range(4)]
alone = [solve("fista-tv", op, g, iters=10, tau=0.05).x for g in gs]
with ThreadPoolExecutor(2) as ex:
    together = list(ex.map(lambda g: solve("fista-tv", op, g, iters=10, tau=0.05).x, gs))
assert all(np.array_equal(a, b) for a, b in zip(alone, together))
import numba
print(numba.threading_layer())
"""


def test_concurrent_launches_survive_the_workqueue_layer():
    # Without OpenMP or TBB Numba falls back to its "workqueue" layer, which aborts the
    # process when two threads launch kernels at once; recon.kernels makes them take turns.
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, NUMBA_THREADING_LAYER="workqueue")
    root = Path(__file__).resolve().parents[3]
    r = subprocess.run([sys.executable, "-c", _CHILD], env=env, cwd=root, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "workqueue"


def test_squared_distance_matches_numpy_in_float64():
    from recon.kernels.vector import squared_distance

    rng = np.random.default_rng(12)
    # Longer than one block; values of very different size, so float32 sums would be off.
    a = (rng.standard_normal((3, 211, 173)) * 1e3).astype(np.float32)
    b = a + rng.standard_normal(a.shape).astype(np.float32) * 1e-3
    want = float(np.sum((a.astype(np.float64) - b) ** 2))
    assert squared_distance(a, b) == pytest.approx(want, rel=1e-12)
    assert squared_distance(a, a) == 0.0


def test_psnr_history_is_the_same_through_the_kernel():
    from recon.app import reconstruct
    from recon.operators import standard_cassi

    rng = np.random.default_rng(13)
    op = standard_cassi((rng.random((16, 20)) < 0.5).astype(np.float32), step=1, n_bands=4)
    truth = rng.random((16, 20, 4)).astype(np.float32)
    g = op.forward(np.ascontiguousarray(np.moveaxis(truth, 2, 0)))
    _, info = reconstruct(g, op, solver="fista-tv", iters=5, truth=truth)
    with kernels.numpy_only():
        _, ref = reconstruct(g, op, solver="fista-tv", iters=5, truth=truth)
    np.testing.assert_allclose(info["psnr_history"], ref["psnr_history"], rtol=0, atol=1e-3)
