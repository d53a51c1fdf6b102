"""The subspace priors' kernels (recon.kernels.subspace) against NumPy."""

import numpy as np
import pytest

from recon import kernels

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


def test_gram_project_expand():
    from recon.kernels import subspace as ks

    rng = np.random.default_rng(0)
    v = rng.random((9, 3 * 4096 + 17)).astype(np.float32)   # blocks with a ragged last one
    partial = np.empty((ks.blocks(v.shape[1]), 9, 9))
    ks.gram(v, partial)
    m = v.astype(np.float64)
    np.testing.assert_allclose(partial.sum(axis=0), m @ m.T, rtol=1e-6)
    e = np.linalg.qr(rng.standard_normal((9, 4)))[0].astype(np.float32)
    z = np.empty((4, v.shape[1]), np.float32)
    ks.mix(np.ascontiguousarray(e.T), v, z)                 # the projection E^T v
    np.testing.assert_allclose(z, e.T @ v, rtol=1e-5, atol=1e-5)
    x = np.empty_like(v)
    ks.mix(e, z, x)                                         # the expansion E z
    np.testing.assert_allclose(x, e @ z, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("n_bands", [1, 2, 4, 5, 26])
def test_gram_tiles_cover_every_band_pair_once(n_bands):
    """The 4 × 4 tiles of band pairs: band counts that do not fill the last tile, signed
    values (the sums cancel), runs and blocks with ragged ends."""
    from recon.kernels import subspace as ks

    rng = np.random.default_rng(n_bands)
    v = (rng.standard_normal((n_bands, 2 * 4096 + 700)) + 0.3).astype(np.float32)
    partial = np.empty((ks.blocks(v.shape[1]), n_bands, n_bands))
    ks.gram(v, partial)
    got = partial.sum(axis=0)
    m = v.astype(np.float64)
    ref = m @ m.T
    assert np.array_equal(got, got.T)
    # float32 sums over runs of 512 pixels: ~1e-7 of the largest entry.
    assert np.abs(got - ref).max() <= 1e-6 * np.abs(ref).max()
    np.testing.assert_allclose(np.diag(got), np.diag(ref), rtol=1e-6)


def test_jacobi_eigh():
    from recon.kernels import subspace as ks

    rng = np.random.default_rng(1)
    a = rng.standard_normal((28, 28))
    a = a @ a.T
    w, v = ks.jacobi_eigh(a.copy(), 1e-12, 50)
    w_ref = np.linalg.eigvalsh(a)
    np.testing.assert_allclose(np.sort(w), w_ref, rtol=1e-9, atol=1e-9 * w_ref.max())
    np.testing.assert_allclose(v.T @ v, np.eye(28), atol=1e-10)
    np.testing.assert_allclose(v @ np.diag(w) @ v.T, a, atol=1e-9 * np.abs(a).max())


@pytest.mark.parametrize("p_rows,q_rows", [(1, 1), (3, 5), (4, 4), (5, 9), (7, 26), (26, 7)])
def test_mix_tiles_every_row(p_rows, q_rows):
    """C src by tiles of four rows of each: row counts that do not fill the last tile (their
    spare rows go to a scratch, not into another row), source counts with a remainder, runs
    and blocks with ragged ends."""
    from recon.kernels import subspace as ks

    rng = np.random.default_rng(10 * p_rows + q_rows)
    c = rng.standard_normal((p_rows, q_rows)).astype(np.float32)
    src = rng.standard_normal((q_rows, 2 * 4096 + 700)).astype(np.float32)
    dst = np.full((p_rows, src.shape[1]), np.nan, np.float32)
    ks.mix(c, src, dst)
    ref = c.astype(np.float64) @ src.astype(np.float64)
    assert np.abs(dst - ref).max() <= 1e-6 * np.abs(ref).max()
