"""BandWarpCassi: a homography per view and band, g_k = sum_l C_kl * W_kl f_l."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import BandWarpCassi, HomographyWarp, dot_test


def random_setup(seed, k=3, n_bands=4, shape=(6, 7), box=(6, 10)):
    rng = np.random.default_rng(seed)
    masks = (rng.random((k, n_bands) + box) > 0.5) * rng.uniform(0.5, 1.0, (k, n_bands) + box)
    warps = []
    for _ in range(k):
        row = []
        for l in range(n_bands):
            # A mirror flip for some views, a per-band scale and shift along x (the prism).
            sx = rng.choice([-1.0, 1.0]) * rng.uniform(0.95, 1.05)
            m = np.array([[sx, rng.uniform(-0.05, 0.05), (box[1] - 1) / 2 - sx * (shape[1] - 1) / 2
                           + 0.7 * l],
                          [rng.uniform(-0.02, 0.02), rng.uniform(0.97, 1.03), rng.uniform(-0.3, 0.3)],
                          [0.0, 0.0, 1.0]])
            row.append(HomographyWarp(m, shape, box))
        warps.append(row)
    return masks.astype(np.float32), warps


def dense(masks, warps):
    rows = []
    for k, row in enumerate(warps):
        rows.append(np.hstack([np.diag(masks[k, l].astype(np.float64).ravel())
                               @ w.matrix().toarray() for l, w in enumerate(row)]))
    return np.vstack(rows)


@pytest.mark.parametrize("seed", range(4))
def test_matches_dense_reference_and_adjoint(seed):
    masks, warps = random_setup(seed)
    op = BandWarpCassi(masks, warps)
    a = dense(masks, warps)
    rng = np.random.default_rng(seed + 100)
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    np.testing.assert_allclose(op.forward(x).ravel(), a @ x.ravel(), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(op.adjoint(y).ravel(), a.T @ y.ravel(), rtol=1e-10, atol=1e-12)
    assert dot_test(op) < 1e-12
    assert op.forward(x.astype(np.float32)).dtype == np.float32
    np.testing.assert_allclose(op.row_norms_sq().ravel(), (a * a).sum(axis=1), rtol=1e-10,
                               atol=1e-12)


def test_bad_input():
    masks, warps = random_setup(0)
    with pytest.raises(InputError):
        BandWarpCassi(masks, warps[:-1])                       # a view missing
    with pytest.raises(InputError):
        BandWarpCassi(masks, [r[:-1] for r in warps])          # a band missing
    with pytest.raises(InputError):
        BandWarpCassi(masks[:, :, :, :-1], warps)              # box does not match the warps
    bad = [list(r) for r in warps]
    bad[1][2] = HomographyWarp(np.eye(3), (5, 7), (6, 10))     # another cube grid
    with pytest.raises(InputError):
        BandWarpCassi(masks, bad)
    bad[1][2] = None
    with pytest.raises(InputError):
        BandWarpCassi(masks, bad)
    nan = masks.copy()
    nan[0, 0, 0, 0] = np.nan
    with pytest.raises(InputError):
        BandWarpCassi(nan, warps)
