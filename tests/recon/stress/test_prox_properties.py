r"""Properties of the TV proximal map over random shapes (hypothesis), complementing
``tests/recon/prox``: non-expansiveness, fixed constants, and the symmetries of
:math:`\mathrm{prox}_{\lambda\mathrm{TV}}`.

For the exact prox: :math:`\|\mathrm{prox}(a)-\mathrm{prox}(b)\| \le \|a-b\|` (proximal maps
of convex functions are firmly non-expansive); an image that is constant in every band has
TV 0 and is its own prox; :math:`\mathrm{prox}(v + c) = \mathrm{prox}(v) + c` for a constant
:math:`c` per band (TV ignores offsets); :math:`\mathrm{prox}_{s\lambda}(sv) =
s\,\mathrm{prox}_\lambda(v)` for :math:`s > 0`; the band means are kept
(:math:`x = v - \lambda\,\mathrm{div}\,p` and :math:`\mathrm{div}` sums to zero).  They are
checked on the *truncated* Chambolle iteration as the solvers use it (1-50 iterations, cold
or warm), in float64, where they hold up to rounding.
"""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from recon.prox import TVProx, prox_tv

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True)

shapes = st.tuples(st.integers(1, 3), st.integers(1, 12), st.integers(1, 12))
weights = st.floats(1e-3, 10.0)
n_iters = st.sampled_from([1, 2, 10, 50])


def _rand(seed, shape, scale=1.0):
    return np.random.default_rng(seed).normal(0.0, scale, shape)


@SETTINGS
@given(shape=shapes, lam=weights, n=n_iters, iso=st.booleans(), seed=st.integers(0, 2**16),
       eps=st.floats(1e-4, 3.0))
def test_non_expansive(shape, lam, n, iso, seed, eps):
    a = _rand(seed, shape)
    b = a + _rand(seed + 1, shape, eps)
    pa, pb = prox_tv(a, lam, n, iso), prox_tv(b, lam, n, iso)
    assert np.linalg.norm(pa - pb) <= np.linalg.norm(a - b) * (1 + 1e-12)


@SETTINGS
@given(shape=shapes, lam=weights, n=n_iters, iso=st.booleans(), seed=st.integers(0, 2**16))
def test_non_expansive_with_a_shared_warm_dual(shape, lam, n, iso, seed):
    """Inside the solvers the dual is carried over; the map v -> prox(v) from one fixed
    warm dual must be non-expansive too."""
    warm = TVProx(shape, np.float64, iso, threads=1)
    warm(_rand(seed + 2, shape), lam, 5)
    dual = warm.dual.copy()
    a, b = _rand(seed, shape), _rand(seed + 1, shape)
    outs = []
    for v in (a, b):
        p = TVProx(shape, np.float64, iso, threads=1)
        p.dual[...] = dual
        outs.append(p(v, lam, n, warm=True))
    assert np.linalg.norm(outs[0] - outs[1]) <= np.linalg.norm(a - b) * (1 + 1e-12)


@SETTINGS
@given(shape=shapes, lam=weights, n=n_iters, iso=st.booleans(), seed=st.integers(0, 2**16),
       dtype=st.sampled_from([np.float32, np.float64]))
def test_constant_image_is_its_own_prox(shape, lam, n, iso, seed, dtype):
    c = np.random.default_rng(seed).uniform(-5, 5, (shape[0], 1, 1))
    v = np.broadcast_to(c, shape).astype(dtype)
    out = prox_tv(v, lam, n, iso)
    assert out.dtype == dtype and np.array_equal(out, v)


@SETTINGS
@given(shape=shapes, lam=weights, n=n_iters, iso=st.booleans(), seed=st.integers(0, 2**16))
def test_offset_equivariance_and_kept_means(shape, lam, n, iso, seed):
    v = _rand(seed, shape)
    c = np.random.default_rng(seed + 7).uniform(-3, 3, (shape[0], 1, 1))
    p = prox_tv(v, lam, n, iso)
    np.testing.assert_allclose(prox_tv(v + c, lam, n, iso), p + c, rtol=0, atol=1e-10)
    np.testing.assert_allclose(p.mean(axis=(1, 2)), v.mean(axis=(1, 2)), rtol=0, atol=1e-10)


@SETTINGS
@given(shape=shapes, lam=weights, n=n_iters, iso=st.booleans(), seed=st.integers(0, 2**16),
       s=st.floats(1e-3, 1e3))
def test_scale_equivariance(shape, lam, n, iso, seed, s):
    v = _rand(seed, shape)
    p = prox_tv(v, lam, n, iso)
    np.testing.assert_allclose(prox_tv(s * v, s * lam, n, iso), s * p, rtol=1e-9,
                               atol=1e-12 * s)
