"""The spectral subspace prior (recon.priors.subspace) against plain NumPy references."""

import numpy as np
import pytest

from cases import reference_subspace
from recon import kernels
from recon.errors import InputError
from recon.priors import make_prior
from recon.priors.base import Prior
from recon.priors.subspace import (SubspaceTV, band_gram, basis_change, default_rank, expand,
                                   leading_basis, project, symmetric_eigh)
from recon.prox.tv import prox_tv


def low_rank_cube(rank=4, shape=(12, 20, 24), seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    spectra = rng.random((shape[0], rank))
    abundances = rng.random((rank, shape[1] * shape[2]))
    cube = (spectra @ abundances).reshape(shape)
    cube += noise * rng.standard_normal(shape)
    return cube.astype(np.float32)


def test_gram_matches_numpy():
    v = low_rank_cube(noise=0.1)
    m = v.reshape(v.shape[0], -1).astype(np.float64)
    ref = m @ m.T
    np.testing.assert_allclose(band_gram(v), ref, rtol=1e-6)
    with kernels.numpy_only():
        np.testing.assert_allclose(band_gram(v), ref, rtol=1e-12)


def test_symmetric_eigh_matches_numpy():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((15, 15))
    a = a @ a.T
    w, v = symmetric_eigh(a)
    w_ref, v_ref = np.linalg.eigh(a)
    np.testing.assert_allclose(w, w_ref, rtol=1e-10, atol=1e-10 * w_ref.max())
    # Distinct eigenvalues: the vectors agree up to their signs.
    np.testing.assert_allclose(np.abs(v.T @ v_ref), np.eye(15), atol=1e-8)
    np.testing.assert_allclose(v @ np.diag(w) @ v.T, a, atol=1e-9 * np.abs(a).max())


def test_leading_basis_spans_the_cube_and_keeps_signs():
    v = low_rank_cube(rank=3)
    e = leading_basis(v, 3)
    np.testing.assert_allclose(e.T @ e, np.eye(3), atol=1e-10)
    m = v.reshape(v.shape[0], -1).astype(np.float64)
    np.testing.assert_allclose(e @ (e.T @ m), m, atol=1e-4 * np.abs(m).max())
    assert np.all(e.sum(axis=0) >= 0)
    flipped = -e
    again = leading_basis(v, 3, previous=flipped)
    np.testing.assert_allclose(again, flipped, atol=1e-10)


def test_basis_change_measures_the_span_not_the_vectors():
    rng = np.random.default_rng(1)
    e, _ = np.linalg.qr(rng.standard_normal((10, 3)))
    assert basis_change(None, e) is None
    # Signs and a rotation within the span do not count.
    rot, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    assert basis_change(e, -e) == pytest.approx(0.0, abs=1e-12)
    assert basis_change(e, e @ rot) == pytest.approx(0.0, abs=1e-12)
    # One vector turned by an angle a out of the span: ||EE^T - E'E'^T||_F = sqrt(2) sin a.
    out = rng.standard_normal(10)
    out -= e @ (e.T @ out)
    out /= np.linalg.norm(out)
    a = 0.01
    turned = e.copy()
    turned[:, 0] = np.cos(a) * e[:, 0] + np.sin(a) * out
    assert basis_change(e, turned) == pytest.approx(np.sqrt(2) * np.sin(a) / np.sqrt(3),
                                                    rel=1e-9)
    assert basis_change(e, e[:, :2]) == np.inf


def test_state_change_follows_the_basis_between_calls():
    v = low_rank_cube(rank=3, noise=0.05)
    prior = SubspaceTV(0.01, rank=3)
    assert prior.state_change() is None
    prior.prox(v, 1.0)
    assert prior.state_change() is None        # nothing to compare with yet
    before = prior.basis.copy()
    w = v.copy()
    w[0] += 0.3                                 # another spectrum: the basis turns
    prior.prox(w, 1.0)
    assert prior.state_change() == pytest.approx(basis_change(before, prior.basis))
    assert prior.state_change() > 1e-3
    prior.prox(w, 1.0)                          # the same input again: it has settled
    assert prior.state_change() < 1e-6
    prior.reset()
    assert prior.state_change() is None


@pytest.mark.parametrize("numpy_only", [False, True])
def test_project_and_expand_match_numpy(numpy_only):
    v = low_rank_cube(noise=0.2)
    e = leading_basis(v, 5).astype(np.float32)
    m = v.reshape(v.shape[0], -1)
    ctx = kernels.numpy_only() if numpy_only else _null()
    with ctx:
        z = project(e, v)
        x = expand(e, z)
    np.testing.assert_allclose(z.reshape(5, -1), e.T @ m, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(x.reshape(v.shape[0], -1), e @ (e.T @ m), rtol=1e-5, atol=1e-5)


class _null:
    def __enter__(self):
        return self

    def __exit__(self, *a):
        return False


def test_prox_is_the_tv_prox_of_the_coefficients():
    """prox(v) = E prox_{s λ TV}(Eᵀ v): the same number of Chambolle iterations from a cold
    start, with NumPy's basis and TV prox as the reference."""
    v = low_rank_cube(rank=4, noise=0.05)
    weight, step, iters = 0.3, 0.5, 6
    prior = SubspaceTV(weight, rank=4, tv_iters=iters)
    x = prior.prox(v, step)
    e, z = reference_subspace(v, 4)
    ref = (e @ prox_tv(z, step * weight, n_iter=iters).reshape(4, -1)).reshape(v.shape)
    np.testing.assert_allclose(x, ref, atol=2e-4 * np.abs(ref).max())
    # Not the identity: the TV step did something measurable.
    assert np.abs(x - (e @ z.reshape(4, -1)).reshape(v.shape)).max() > 1e-2


def test_output_rank_is_at_most_k():
    v = low_rank_cube(rank=8, noise=0.3)
    for k in (1, 3, 5):
        x = SubspaceTV(0.1, rank=k).prox(v, 1.0)
        s = np.linalg.svd(x.reshape(v.shape[0], -1).astype(np.float64), compute_uv=False)
        assert np.sum(s > 1e-4 * s[0]) <= k


def test_weight_zero_returns_a_cube_already_in_the_subspace():
    v = low_rank_cube(rank=3)
    x = SubspaceTV(0.0, rank=3).prox(v, 1.0)
    np.testing.assert_allclose(x, v, atol=1e-5 * np.abs(v).max())
    # ... and a cube of higher rank is changed (the projection acts).
    w = low_rank_cube(rank=6, seed=1)
    assert np.abs(SubspaceTV(0.0, rank=3).prox(w, 1.0) - w).max() > 1e-2


def test_prox_into_its_input_and_reset():
    v = low_rank_cube(noise=0.1)
    a = SubspaceTV(0.2, rank=4)
    expected = a.prox(v.copy(), 1.0)
    b = SubspaceTV(0.2, rank=4)
    w = v.copy()
    out = b.prox(w, 1.0, out=w)
    assert out is w
    np.testing.assert_array_equal(w, expected)
    b.reset()
    assert b.basis is None
    np.testing.assert_array_equal(b.prox(v, 1.0), expected)


def test_value_is_weighted_tv_of_the_coefficients():
    from recon.prox.tv import tv_norm

    v = low_rank_cube(rank=3)
    prior = SubspaceTV(0.7, rank=3)
    e = leading_basis(v, 3)
    z = (e.T @ v.reshape(v.shape[0], -1).astype(np.float64)).reshape((3,) + v.shape[1:])
    assert prior.value(v) == pytest.approx(0.7 * tv_norm(z), rel=1e-5)


def test_prox_value_is_the_value_of_the_prox_result():
    # The prior's value of its last prox's result, from the coefficient images it already
    # has: the value of that result (float32 rounding apart); nothing before a call or after
    # a reset.
    v = low_rank_cube(noise=0.1)
    prior = SubspaceTV(0.3, rank=4)
    assert prior.prox_value() is None
    x = prior.prox(v, 0.5)
    assert prior.prox_value() == pytest.approx(prior.value(x), rel=1e-5)
    x = prior.prox(v + 0.05, 0.5, out=v)           # in place: still the last result's
    assert prior.prox_value() == pytest.approx(prior.value(x), rel=1e-5)
    prior.reset()
    assert prior.prox_value() is None


@pytest.mark.parametrize("weighted", [False, True])
def test_previous_value_scores_the_previous_result_with_the_new_basis(weighted):
    # The value of the previous prox's result with the basis the last call re-estimated,
    # from its coefficient images: value() of that result called now (float32 rounding
    # apart), with a basis that did turn between the calls; with factors per band the value
    # of the result divided by them (how the band metric takes the prior).  Nothing before
    # two calls, after a reset, or when the rank changed.
    rng = np.random.default_rng(5)
    q = rng.uniform(1.0, 4.0, 12) if weighted else None
    qc = np.ones((12, 1, 1), np.float32) if q is None else q.astype(np.float32)[:, None, None]
    prior = SubspaceTV(0.3, rank=4)
    first = prior.scaled_prox(low_rank_cube(noise=0.1, seed=0), 0.5, q).copy()
    assert prior.previous_value() is None
    v = low_rank_cube(noise=0.1, seed=1)
    v[:3] += 0.2 * low_rank_cube(seed=7)[:3]      # another spectrum: the basis turns
    prior.scaled_prox(v, 0.5, q)
    assert prior.state_change() > 1e-2
    want = prior.value(first / qc)
    assert want != pytest.approx(SubspaceTV(0.3, rank=4).value(first / qc), rel=1e-3)
    assert prior.previous_value() == pytest.approx(want, rel=1e-5)
    prior.rank = 5
    prior.prox(v, 0.5)
    assert prior.previous_value() is None
    prior.reset()
    assert prior.previous_value() is None


def test_scaled_prox_is_the_prox_of_the_weighted_cube():
    # q * prox(q * v) with the factors carried on the basis: the weighted cube's basis, the
    # same result and value as weighing the cube, over two calls (the warm dual and the
    # basis's signs carried).
    from recon.priors.base import scaled_prox

    rng = np.random.default_rng(3)
    q = rng.uniform(1.0, 4.0, 12)
    fast, slow = SubspaceTV(0.3, rank=4), SubspaceTV(0.3, rank=4)
    for seed in (0, 1):
        v = low_rank_cube(noise=0.1, seed=seed)
        got = fast.scaled_prox(v.copy(), 0.5, q)
        want = q[:, None, None] * slow.prox(q[:, None, None].astype(np.float32) * v, 0.5)
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5 * np.abs(want).max())
        np.testing.assert_allclose(fast.basis, slow.basis, atol=1e-5)
        assert fast.prox_value() == pytest.approx(slow.prox_value(), rel=1e-5)
    # The module's helper takes the prior's own; without factors it is the plain prox.
    v = low_rank_cube(noise=0.1, seed=2)
    np.testing.assert_array_equal(scaled_prox(SubspaceTV(0.3, rank=4), v.copy(), 0.5, None),
                                  SubspaceTV(0.3, rank=4).prox(v.copy(), 0.5))


def test_default_rank_follows_the_bands():
    assert default_rank(31) == 8
    assert default_rank(28) == 7
    assert default_rank(11) == 4
    assert default_rank(8) == 4
    assert default_rank(3) == 3
    assert default_rank(2) == 2


def test_bad_inputs():
    with pytest.raises(InputError):
        SubspaceTV(-1.0)
    with pytest.raises(InputError):
        SubspaceTV(0.1, rank=0)
    with pytest.raises(InputError):
        SubspaceTV(0.1, rank=20).prox(low_rank_cube(), 1.0)
    with pytest.raises(InputError):
        SubspaceTV(0.1).prox(np.zeros((4, 4), np.float32), 1.0)


def test_registry_builds_it_with_the_callers_weight():
    prior = make_prior("subspace-tv", shape=(12, 20, 24), weight=0.02, solver="gap", rank=4)
    assert isinstance(prior, Prior)
    assert isinstance(prior, SubspaceTV)
    assert prior.rank == 4 and prior.weight == pytest.approx(0.02)


def test_weight_follows_the_noise_without_a_weight():
    """No weight given: κ n σ̄ for the least-squares solvers, as the application's TV rule."""
    prior = make_prior("subspace-tv", shape=(12, 20, 24), solver="fista-tv", noise=0.02,
                       n_views=5)
    assert prior.weight == pytest.approx(0.15 * 5 * 0.02)
    assert make_prior("subspace-tv", solver="gap").weight == pytest.approx(0.1)
    with pytest.raises(InputError):
        make_prior("subspace-tv", solver="fista", noise=-1.0, n_views=1)
