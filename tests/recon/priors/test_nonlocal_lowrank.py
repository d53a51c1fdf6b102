"""The non-local low-rank subspace prior (recon.priors.nonlocal_lowrank) against plain NumPy
references, in the registry, and inside the solvers that take a plug-and-play prior."""

import numpy as np
import pytest

from cases import reference_subspace
from recon import kernels
from recon.errors import InputError
from recon.operators import standard_cassi
from recon.priors import PRIORS, make_prior
from recon.priors.base import Prior
from recon.priors.nonlocal_lowrank import (DENOISE_ITERS, DENOISE_ITERS_VIEWS, STRENGTH, WARMUP,
                                          SubspaceNLR, denoise_nonlocal, reference_grid)
from recon.priors.subspace import SubspaceTV, leading_basis
from recon.solvers import solve


def smooth_low_rank_cube(rank=3, shape=(10, 28, 30), seed=0, noise=0.0):
    """A cube of ``rank`` spectra whose abundance images are smooth stripes and blobs (the
    kind of image a patch denoiser groups), plus white noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:shape[1], :shape[2]]
    images = [0.5 + 0.5 * np.sin(xx / 3.0 + j) * np.cos(yy / (4.0 + j)) for j in range(rank)]
    spectra = rng.random((shape[0], rank)) + 0.2
    cube = np.einsum("lk,khw->lhw", spectra, np.stack(images))
    cube = cube / cube.max() + noise * rng.standard_normal(shape)
    return cube.astype(np.float32)


def _rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def test_reference_grid_covers_every_pixel():
    for n, p, s in ((30, 6, 4), (17, 5, 5), (6, 6, 3), (40, 4, 4)):
        grid = reference_grid(n, p, s)
        covered = np.zeros(n, bool)
        for g in grid:
            covered[g:g + p] = True
        assert covered.all() and grid[0] == 0 and grid[-1] == n - p
        assert np.all(np.diff(grid) <= s)


def test_warm_up_calls_are_the_subspace_tv_prox():
    v = smooth_low_rank_cube(noise=0.05)
    nlr = SubspaceNLR(0.1, rank=3, warmup=3)
    tv = SubspaceTV(0.1, rank=3)
    for _ in range(3):
        np.testing.assert_array_equal(nlr.prox(v, 0.5), tv.prox(v, 0.5))
    # The fourth call is the non-local denoiser: no longer the TV prox.
    assert np.abs(nlr.prox(v, 0.5) - tv.prox(v, 0.5)).max() > 1e-3
    nlr.reset()
    assert nlr.calls == 0 and nlr.basis is None
    tv.reset()
    np.testing.assert_array_equal(nlr.prox(v, 0.5), tv.prox(v, 0.5))


@pytest.mark.parametrize("numpy_only", [False, True])
def test_denoising_step_is_the_basis_times_the_numpy_denoiser(numpy_only):
    """After the warm-up: E · NLR_σ(Eᵀv), σ = strength · step · weight, with NumPy's basis
    and the NumPy denoiser (float64) as the reference."""
    v = smooth_low_rank_cube(noise=0.05)
    weight, step, strength = 0.2, 0.5, 0.6
    prior = SubspaceNLR(weight, rank=3, warmup=0, strength=strength, patch=5, radius=6,
                        group=10, stride=3)
    if numpy_only:
        with kernels.numpy_only():
            x = prior.prox(v, step)
    else:
        x = prior.prox(v, step)
    e, z = reference_subspace(v, 3)
    with kernels.numpy_only():
        zd = denoise_nonlocal(z, np.full(3, strength * step * weight), patch=5, radius=6,
                              group=10, stride=3)
    ref = (e @ zd.reshape(3, -1)).reshape(v.shape)
    np.testing.assert_allclose(x, ref, atol=2e-5 * np.abs(ref).max())


def test_it_denoises_better_than_the_projection_alone():
    clean = smooth_low_rank_cube(shape=(10, 40, 44))
    sigma = 0.05
    noisy = smooth_low_rank_cube(shape=(10, 40, 44), noise=sigma)
    projected = SubspaceTV(0.0, rank=3).prox(noisy, 1.0)
    # σ = strength · step · weight = the noise's deviation.
    x = SubspaceNLR(sigma, rank=3, warmup=0, strength=1.0, patch=5, group=16).prox(noisy, 1.0)
    assert _rmse(x, clean) < 0.6 * _rmse(projected, clean)
    # ... and the output stays in the k-dimensional subspace.
    s = np.linalg.svd(x.reshape(10, -1).astype(np.float64), compute_uv=False)
    assert np.sum(s > 1e-4 * s[0]) <= 3


def test_zero_weight_is_the_projection():
    v = smooth_low_rank_cube(rank=5, noise=0.1)
    x = SubspaceNLR(0.0, rank=3, warmup=0).prox(v, 1.0)
    e = leading_basis(v, 3)
    m = v.reshape(v.shape[0], -1).astype(np.float64)
    np.testing.assert_allclose(x.reshape(v.shape[0], -1), e @ (e.T @ m), atol=1e-5)


def test_bad_inputs():
    with pytest.raises(InputError):
        SubspaceNLR(-0.1)
    with pytest.raises(InputError):
        SubspaceNLR(0.1, strength=float("nan"))
    with pytest.raises(InputError):
        SubspaceNLR(0.1, patch=0)
    with pytest.raises(InputError):
        SubspaceNLR(0.1, group=1)
    with pytest.raises(InputError):
        SubspaceNLR(0.1, warmup=-1)
    with pytest.raises(InputError, match="or rule"):
        SubspaceNLR(0.1, warmup="solve")
    with pytest.raises(InputError, match="denoise_iters"):
        SubspaceNLR(0.1, warmup="rule", denoise_iters=0)
    with pytest.raises(InputError, match="stride"):
        SubspaceNLR(0.1, patch=4, stride=5)     # pixels between the references uncovered
    with pytest.raises(InputError):
        denoise_nonlocal(np.zeros((2, 8, 8), np.float32), [1.0, 0.0])
    with pytest.raises(InputError):
        denoise_nonlocal(np.zeros((2, 4, 4), np.float32), [1.0, 1.0], patch=6)


def test_registry_builds_it_with_the_callers_weight():
    assert "subspace-nlr" in PRIORS
    prior = make_prior("subspace-nlr", shape=(12, 20, 24), weight=0.02, solver="gap", rank=4,
                       warmup=7)
    assert isinstance(prior, Prior) and isinstance(prior, SubspaceNLR)
    assert (prior.rank, prior.warmup, prior.weight) == (4, 7, pytest.approx(0.02))
    # Without a weight: the noise rule of the least-squares solvers, as subspace-tv.
    p = make_prior("subspace-nlr", solver="fista", noise=0.02, n_views=5)
    assert p.weight == pytest.approx(0.15 * 5 * 0.02)


@pytest.mark.parametrize("solver", ["gap-tv", "gap", "admm", None, "fista-tv", "fista"])
def test_strength_and_warm_up_follow_the_solver(solver):
    """GAP (and the solvers without a measured setting) warm up for a count of calls at
    strength 1; FISTA warms up with a whole subspace-TV solve and denoises at its own
    strength; options given win."""
    p = make_prior("subspace-nlr", shape=(12, 20, 24), weight=0.02, solver=solver)
    fista = solver is not None and solver.startswith("fista")
    assert (p.strength, p.warmup) == ((STRENGTH["fista"], "rule") if fista
                                      else (STRENGTH["gap"], WARMUP["gap"]))
    assert (p.stages() is not None) == fista
    q = make_prior("subspace-nlr", weight=0.02, solver=solver, strength=2.5, warmup=5)
    assert (q.strength, q.warmup, q.stages()) == (2.5, 5, None)


def test_denoiser_iterations_follow_the_views():
    for views, want in ((None, DENOISE_ITERS), (1, DENOISE_ITERS), (2, DENOISE_ITERS_VIEWS),
                        (5, DENOISE_ITERS_VIEWS)):
        p = make_prior("subspace-nlr", weight=0.02, solver="fista-tv", n_views=views)
        assert p.stages()[1] == want
    p = make_prior("subspace-nlr", weight=0.02, solver="fista-tv", n_views=5, denoise_iters=7)
    assert p.stages()[1] == 7
    assert DENOISE_ITERS_VIEWS < DENOISE_ITERS


def test_rule_warm_up_hands_over_the_subspace_tv_prior():
    """With warmup="rule" the first stage is subspace-TV with the same weight, rank and TV
    options, and every call of the prior itself is the denoiser."""
    v = smooth_low_rank_cube(noise=0.05)
    nlr = SubspaceNLR(0.1, rank=3, warmup="rule", denoise_iters=7, tv_iters=3)
    first, n = nlr.stages()
    assert n == 7 and type(first) is SubspaceTV
    assert (first.weight, first.rank, first.tv_iters) == (0.1, 3, 3)
    assert nlr.describe()["denoise_iters"] == 7
    tv = SubspaceTV(0.1, rank=3, tv_iters=3)
    np.testing.assert_array_equal(first.prox(v, 0.5), tv.prox(v, 0.5))
    e = leading_basis(v, 3)
    z = np.einsum("lk,lhw->khw", e, v.astype(np.float64))
    den = denoise_nonlocal(z.astype(np.float32), np.full(3, nlr.strength * 0.5 * 0.1))
    np.testing.assert_allclose(nlr.prox(v, 0.5), np.einsum("lk,khw->lhw", e, den), atol=2e-5)


def _cassi_problem():
    truth = smooth_low_rank_cube(shape=(8, 32, 32), seed=4)
    rng = np.random.default_rng(5)
    op = standard_cassi((rng.random((32, 32)) > 0.5).astype(np.float32), 1, 8)
    g = np.asarray(op.forward(truth), np.float32)
    return op, g + rng.normal(0, 0.002, g.shape).astype(np.float32), truth


@pytest.mark.parametrize("solver,weight", [("gap-tv", 0.05), ("fista-tv", 0.2),
                                           ("admm", 0.2)])
def test_solvers_take_it(solver, weight):
    """Each solver that takes a plug-and-play prior runs through the warm-up into the
    non-local denoiser and ends far closer to the truth than its start."""
    op, g, truth = _cassi_problem()
    prior = SubspaceNLR(weight, rank=3, warmup=10, patch=4, radius=5, group=8)
    res = solve(solver, op, g, iters=60, prior=prior)
    assert prior.calls > prior.warmup
    assert np.all(np.isfinite(res.x))
    start = np.asarray(op.adjoint(g), np.float64)
    start *= np.vdot(start, truth) / np.vdot(start, start)     # the best-scaled adjoint
    assert _rmse(res.x, truth) < 0.5 * _rmse(start, truth)


def test_twist_refuses_it():
    op, g, _ = _cassi_problem()
    with pytest.raises(InputError, match="prior with a value"):
        solve("twist", op, g, iters=3, prior=SubspaceNLR(0.05, rank=3))
