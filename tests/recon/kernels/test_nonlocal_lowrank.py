"""The non-local low-rank denoiser's kernels (recon.kernels.nonlocal_lowrank) against plain
NumPy: block matching by brute force, the group filters from NumPy's SVD, and the whole
denoiser against its NumPy path (recon.priors.nonlocal_lowrank.denoise_nonlocal)."""

import numpy as np
import pytest

from recon import kernels

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


def _images(k=3, h=23, w=27, seed=0):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((k, h, w)).astype(np.float32)


def test_match_is_the_brute_force_nearest_patches():
    from recon.kernels import nonlocal_lowrank as kn
    from recon.priors.nonlocal_lowrank import _references

    z = _images()
    patch, radius, m = 4, 5, 7
    ry, rx = _references(z.shape[1:], patch, 3)
    idx_y = np.empty((ry.size, m), np.int64)
    idx_x = np.empty_like(idx_y)
    guide = np.ascontiguousarray(z[:2])
    kn.match(guide, ry, rx, patch, radius, idx_y, idx_x)
    h, w = z.shape[1:]
    g64 = guide.astype(np.float64)
    for g, (y0, x0) in enumerate(zip(ry, rx)):
        cands = [(y, x) for y in range(max(0, y0 - radius), min(h - patch, y0 + radius) + 1)
                 for x in range(max(0, x0 - radius), min(w - patch, x0 + radius) + 1)]
        ref = g64[:, y0:y0 + patch, x0:x0 + patch]
        dist = np.array([((g64[:, y:y + patch, x:x + patch] - ref) ** 2).sum()
                         for y, x in cands])
        ref = cands.index((y0, x0))
        order = np.argsort(dist, kind="stable")
        best = np.concatenate(([ref], order[order != ref]))[:m]
        np.testing.assert_array_equal(idx_y[g], [cands[i][0] for i in best])
        np.testing.assert_array_equal(idx_x[g], [cands[i][1] for i in best])
        assert (idx_y[g, 0], idx_x[g, 0]) == (y0, x0)    # the reference itself first


def test_a_flat_guide_keeps_every_reference_in_its_group():
    """Where more patches than a group holds tie with the reference (a flat region of the
    guide, e.g. a part of the cube no view sees) the reference still leads its group, so
    every pixel gets an estimate: before, the groups took the first patches of the scan and
    pixels that no group held came out 0/0 = NaN."""
    from recon.kernels import nonlocal_lowrank as kn
    from recon.priors.nonlocal_lowrank import _references, denoise_nonlocal

    rng = np.random.default_rng(4)
    z = np.zeros((2, 40, 40), np.float32)
    z[1] = rng.random((40, 40))
    z[0, 30:, 30:] = rng.random((10, 10))          # flat except one corner
    patch, m = 4, 24
    ry, rx = _references(z.shape[1:], patch, 4)
    idx_y = np.empty((ry.size, m), np.int64)
    idx_x = np.empty_like(idx_y)
    kn.match(np.ascontiguousarray(z[:1]), ry, rx, patch, 10, idx_y, idx_x)
    np.testing.assert_array_equal(idx_y[:, 0], ry)
    np.testing.assert_array_equal(idx_x[:, 0], rx)
    got = denoise_nonlocal(z, np.ones(2))
    assert np.all(np.isfinite(got))
    with kernels.numpy_only():
        ref = denoise_nonlocal(z.astype(np.float64), np.ones(2))
    assert np.all(np.isfinite(ref))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5 * np.abs(ref).max())


def test_shrink_is_gavish_donohos_optimal_shrinker():
    from recon.kernels import nonlocal_lowrank as kn
    from recon.priors.nonlocal_lowrank import shrink_factors

    d, m, sigma = 20, 5, 1.5
    unit2 = d * sigma ** 2                      # (sqrt(max(d, m)) sigma)^2
    beta = m / d
    y = np.array([6.0, 3.0, 1.0 + np.sqrt(beta) + 1e-3, 1.2, 0.5, 0.0])
    s2 = y ** 2 * unit2
    f = kn.shrink(s2, d, m, sigma ** 2)
    # The formula written out: s' = sqrt(n) sigma sqrt((y^2 - beta - 1)^2 - 4 beta) / y.
    s_new = np.sqrt(unit2) * np.sqrt(np.maximum((y ** 2 - beta - 1) ** 2 - 4 * beta, 0)) / \
        np.where(y > 0, y, 1)
    ref = np.where(y > 1 + np.sqrt(beta), s_new / np.where(y > 0, y * np.sqrt(unit2), 1), 0)
    np.testing.assert_allclose(f, ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(shrink_factors(s2, d, m, sigma), ref, rtol=1e-12, atol=1e-15)
    assert 0.9 < f[0] < 1 and 0 < f[2] < 0.1 and np.all(f[3:] == 0)   # the bulk removed
    # The same for a wide matrix (d < m): the rule is symmetric in d and m.
    np.testing.assert_allclose(kn.shrink(s2, m, d, sigma ** 2), ref, rtol=1e-12, atol=1e-15)


def test_group_filters_match_numpys_svd():
    from recon.kernels import nonlocal_lowrank as kn
    from recon.priors.nonlocal_lowrank import _references

    z = _images(seed=1)
    patch, m, strength = 3, 6, 0.7
    scale = np.array([1.0, 0.5, 2.0])
    ry, rx = _references(z.shape[1:], patch, 5)
    idx_y = np.empty((ry.size, m), np.int64)
    idx_x = np.empty_like(idx_y)
    kn.match(np.ascontiguousarray(z[:1]), ry, rx, patch, 4, idx_y, idx_x)
    d = z.shape[0] * patch * patch
    filt = np.empty((ry.size, m, m))
    ranks = np.empty(ry.size, np.int64)
    means = np.empty((ry.size, d))
    kn.group_filters(z, scale, idx_y, idx_x, patch, strength, filt, ranks, means)
    zs = z.astype(np.float64) * scale[:, None, None]
    for g in range(ry.size):
        y = np.stack([zs[:, a:a + patch, b:b + patch].ravel()
                      for a, b in zip(idx_y[g], idx_x[g])], axis=1)
        mu = y.mean(axis=1)
        np.testing.assert_allclose(means[g], mu, rtol=1e-6, atol=1e-6)
        yc = y - mu[:, None]
        u, s, vt = np.linalg.svd(yc, full_matrices=False)
        y2 = s ** 2 / (max(d, m) * strength ** 2)
        beta = min(d, m) / max(d, m)
        root = np.sqrt(np.maximum((y2 - beta - 1) ** 2 - 4 * beta, 0))
        s_new = np.where(np.sqrt(y2) > 1 + np.sqrt(beta), s * root / np.maximum(y2, 1e-300), 0)
        assert 0 < np.count_nonzero(s_new) < m      # some values kept, some removed
        # The filtered group two ways: U S' Vᵀ (NumPy's SVD) and Yc B Bᵀ (the kernel's B).
        b = filt[g, :, :ranks[g]]
        assert ranks[g] == np.count_nonzero(s_new)
        np.testing.assert_allclose(yc @ b @ b.T, (u * s_new) @ vt, atol=1e-6 * s[0])


def test_the_denoiser_matches_its_numpy_path():
    from recon.priors.nonlocal_lowrank import denoise_nonlocal

    rng = np.random.default_rng(2)
    k, h, w = 3, 30, 34
    yy, xx = np.mgrid[:h, :w]
    clean = np.stack([np.sin(yy / 3 + j) * np.cos(xx / 4) for j in range(k)])
    z = (clean + 0.1 * rng.standard_normal(clean.shape)).astype(np.float32)
    sig = np.array([0.1, 0.12, 0.09])
    opts = dict(strength=1.3, patch=5, radius=6, group=8, stride=3)
    fast = denoise_nonlocal(z, sig, **opts)
    with kernels.numpy_only():
        ref = denoise_nonlocal(z, sig, **opts)
    assert fast.dtype == np.float32 and ref.dtype == np.float64
    np.testing.assert_allclose(fast, ref, atol=2e-6 * np.abs(ref).max())
    # And it denoises: the error falls well below the noise.
    assert np.sqrt(np.mean((fast - clean) ** 2)) < 0.7 * np.sqrt(np.mean((z - clean) ** 2))
