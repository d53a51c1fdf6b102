"""Non-local means on the subspace's eigenimages (recon.priors.subspace_nlm) against a plain
NumPy + scikit-image reference."""

import numpy as np
import pytest
from skimage.restoration import denoise_nl_means

from recon.errors import InputError
from recon.priors import make_prior
from recon.priors.subspace_nlm import SubspaceNLM


def cube(rank=4, shape=(10, 24, 28), seed=0, noise=0.05):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:shape[1], 0:shape[2]] / max(shape[1:])
    maps = np.stack([np.cos(3 * (i + 1) * xx + i) * np.sin(2 * yy + i) for i in range(rank)])
    spectra = rng.random((shape[0], rank))
    c = (spectra @ (maps.reshape(rank, -1) + 1.5)).reshape(shape)
    return (c + noise * rng.standard_normal(shape)).astype(np.float32)


def reference(v, rank, sigma):
    m = v.reshape(v.shape[0], -1).astype(np.float64)
    _, vecs = np.linalg.eigh(m @ m.T)
    e = vecs[:, ::-1][:, :rank]
    e *= np.sign(e.sum(axis=0))
    z = (e.T @ m).reshape((rank,) + v.shape[1:])
    z = np.stack([denoise_nl_means(zi, patch_size=5, patch_distance=6, h=0.8 * sigma,
                                   sigma=sigma, fast_mode=True, preserve_range=True)
                  for zi in z])
    return (e @ z.reshape(rank, -1)).reshape(v.shape)


def test_matches_the_reference_and_denoises():
    clean = cube(noise=0.0)
    v = cube(noise=0.05)
    x = SubspaceNLM(0.1, rank=4).prox(v, 0.5)
    ref = reference(v, 4, 0.05)
    np.testing.assert_allclose(x, ref, atol=1e-3 * np.abs(ref).max())
    assert np.mean((x - clean) ** 2) < 0.5 * np.mean((v - clean) ** 2)


def test_rank_and_weight_zero():
    v = cube(rank=3, noise=0.0)
    x = SubspaceNLM(0.0, rank=3).prox(v, 1.0)
    np.testing.assert_allclose(x, v, atol=1e-5 * np.abs(v).max())
    y = SubspaceNLM(0.1, rank=2).prox(cube(rank=6, noise=0.1), 1.0)
    s = np.linalg.svd(y.reshape(y.shape[0], -1).astype(np.float64), compute_uv=False)
    assert np.sum(s > 1e-4 * s[0]) <= 2


def test_is_a_denoiser_and_in_the_registry():
    prior = make_prior("subspace-nlm", shape=(10, 24, 28), weight=0.03, solver="gap", rank=3)
    assert isinstance(prior, SubspaceNLM) and prior.weight == pytest.approx(0.03)
    assert prior.value(cube()) is None
    with pytest.raises(InputError):
        SubspaceNLM(float("nan"))
