"""The TV prox fused with a CASSI gradient step (:meth:`recon.prox.TVProx.gradient_prox`, the
gather of :func:`recon.kernels.tv.chambolle`) against the NumPy path it replaces:
``adjoint_add`` then the prox, in float32.  Sizes are small and odd, as in test_kernels.py."""

import numpy as np
import pytest

from kernel_checks import RTOL32, permutation_cassi, rel, warped_cassi
from recon import kernels
from recon.operators import CassiOperator
from recon.prox import TVProx
from recon.solvers import gap_tv

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


OPS = permutation_cassi(np.random.default_rng(21))
WARPED = warped_cassi(np.random.default_rng(22))


def _problem(op, seed):
    rng = np.random.default_rng(seed)
    base = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    dual = rng.uniform(-0.7, 0.7, (2,) + op.ishape).astype(np.float32)
    return base, y, dual


@pytest.mark.parametrize("name", sorted(OPS))
def test_every_permutation_operator_offers_the_gather(name):
    y = np.zeros(OPS[name].oshape, np.float32)
    assert OPS[name].adjoint_gather(y, 0.5, np.float32) is not None
    # Too large for the budget, float64 or kernels off: no gather (the callers fall back).
    assert OPS[name].adjoint_gather(y, 0.5, np.float32, max_bytes=0) is None
    assert OPS[name].adjoint_gather(y, 0.5, np.float64) is None
    with kernels.numpy_only():
        assert OPS[name].adjoint_gather(y, 0.5, np.float32) is None
    assert WARPED.adjoint_gather(np.zeros(WARPED.oshape, np.float32)) is None


@pytest.mark.parametrize("name", sorted(OPS))
def test_gather_is_the_scaled_adjoint(name):
    # The documented formula, evaluated in NumPy, gives s H^T y.
    op = OPS[name]
    _, y, _ = _problem(op, 24)
    z, masks, a, c0, c1, sub = op.adjoint_gather(y, 0.37, np.float32)
    n_bands, h, w = op.ishape
    got = np.zeros(op.ishape, np.float64)
    for k in range(masks.shape[0]):
        for l in range(n_bands):
            taps = c0[k, l] * z[k, :, a[k, l]:a[k, l] + w]
            if sub[k, l]:
                taps = taps + c1[k, l] * z[k, :, a[k, l] + 1:a[k, l] + 1 + w]
            got[l] += masks[k] * taps
    assert rel(got, 0.37 * op.adjoint(y.astype(np.float64))) < RTOL32


@pytest.mark.parametrize("name", sorted(OPS))
@pytest.mark.parametrize("n_iter", [0, 1, 2, 5])
@pytest.mark.parametrize("isotropic", [True, False])
@pytest.mark.parametrize("in_place", [False, True])
def test_fused_step_matches_adjoint_add_then_prox(name, n_iter, isotropic, in_place):
    op = OPS[name]
    base, y, dual = _problem(op, 25)
    prox = TVProx(op.ishape, np.float32, isotropic, threads=2)
    prox.dual[:] = dual
    b = base.copy()
    x = prox.gradient_prox(op, y, b, 0.3, n_iter, scale=0.7, out=b if in_place else None)
    assert x.dtype == np.float32 and (x is b) == in_place
    if not in_place:
        assert np.array_equal(b, base)
    ref = TVProx(op.ishape, np.float32, isotropic, threads=2)
    ref.dual[:] = dual
    with kernels.numpy_only():
        v = op.adjoint_add(y, base, 0.7)
        x_ref = ref(v, 0.3, n_iter, out=v)
    assert rel(x, x_ref) < RTOL32 * (1 + n_iter)
    assert rel(prox.dual, ref.dual) < RTOL32 * (1 + n_iter)


def test_fused_step_cold_start_and_zero_weight():
    op = OPS["kaleido9-sub"]
    base, y, dual = _problem(op, 26)
    prox, ref = TVProx(op.ishape), TVProx(op.ishape)
    prox.dual[:] = dual
    x = prox.gradient_prox(op, y, base, 0.2, 3, warm=False, scale=0.5)
    with kernels.numpy_only():
        x_ref = ref(op.adjoint_add(y, base, 0.5), 0.2, 3)
    assert rel(x, x_ref) < 4 * RTOL32 and rel(prox.dual, ref.dual) < 4 * RTOL32
    # No TV: the plain gradient step.
    assert rel(prox.gradient_prox(op, y, base, 0.0, 3, scale=0.5),
               op.adjoint_add(y, base, 0.5)) < RTOL32


def test_warped_views_take_the_two_calls():
    base, y, dual = _problem(WARPED, 27)
    prox, ref = TVProx(WARPED.ishape), TVProx(WARPED.ishape)
    prox.dual[:] = ref.dual[:] = dual
    x = prox.gradient_prox(WARPED, y, base, 0.3, 2, scale=0.7)
    x_ref = ref(WARPED.adjoint_add(y, base, 0.7), 0.3, 2)
    assert np.array_equal(x, x_ref) and np.array_equal(prox.dual, ref.dual)


def test_fused_step_does_not_depend_on_threads():
    op = OPS["kaleido9-sub"]
    base, y, dual = _problem(op, 28)
    outs = []
    for n in (1, 2, 3):
        prox = TVProx(op.ishape, threads=n)
        prox.dual[:] = dual
        outs.append(prox.gradient_prox(op, y, base, 0.3, 2, scale=0.7))
    assert all(np.array_equal(outs[0], o) for o in outs[1:])


@pytest.mark.parametrize("name", ["standard-int", "standard-neg-sub", "kaleido9-sub"])
def test_gap_tv_fused_matches_unfused(name, monkeypatch):
    # The solver through the fused step, through the two kernels one after the other (no
    # gather offered) and through the NumPy path: the same reconstruction.
    op = OPS[name]
    truth = np.random.default_rng(29).random(op.ishape).astype(np.float32)
    g = op.forward(truth)
    fused = gap_tv(op, g, iters=20, tau=0.05)
    with kernels.numpy_only():
        numpy_path = gap_tv(op, g, iters=20, tau=0.05)
    monkeypatch.setattr(CassiOperator, "adjoint_gather", lambda self, *a, **k: None)
    unfused = gap_tv(op, g, iters=20, tau=0.05)
    # 20 iterations of a nonlinear map amplify roundings a little, no more (as in
    # test_kernels.test_solvers_agree_with_the_numpy_path); the two kernel paths differ by
    # the order of a few sums only (one view: not at all).
    assert rel(fused.x, unfused.x) < 1e-5
    assert rel(fused.x, numpy_path.x) < 1e-4
