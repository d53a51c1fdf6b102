"""What every fused-kernel test compares: a kernel's float32 result against the plain NumPy path
it replaces (reached through the same public calls inside ``kernels.numpy_only()``)."""

import numpy as np

from recon import kernels

# float32 rounding is 6e-8; the kernels reorder sums and contract multiply-adds, so they
# differ from NumPy by a few roundings, never more.
RTOL32 = 1e-6


def rel(a, b) -> float:
    """Largest absolute difference relative to the largest entry of ``b``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))


def assert_operator_matches_numpy(op, seed: int) -> None:
    """``op.forward`` and ``op.adjoint`` of random float32 inputs: float32, of the operator's
    shapes, and within :data:`RTOL32` of the NumPy path."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    fwd, adj = op.forward(x), op.adjoint(y)
    with kernels.numpy_only():
        fwd_ref, adj_ref = op.forward(x), op.adjoint(y)
    assert fwd.dtype == adj.dtype == np.float32
    assert fwd.shape == op.oshape and adj.shape == op.ishape
    assert rel(fwd, fwd_ref) < RTOL32
    assert rel(adj, adj_ref) < RTOL32


def permutation_cassi(rng) -> dict:
    """CASSI operators whose views are all permutations (the fused kernels' plans), small and
    odd-sized: integer and negative sub-pixel shifts, 9 and 5 views, per-view offsets, one
    band, one row, one column."""
    from recon.operators import kaleidoscope_cassi, standard_cassi

    return {
        "standard-int": standard_cassi((rng.random((13, 17)) > 0.5).astype(np.float32), 2, 5),
        "standard-neg-sub": standard_cassi(rng.random((13, 17)).astype(np.float32), -1.3, 5),
        "kaleido9-sub": kaleidoscope_cassi(rng.random((9, 11, 14)).astype(np.float32),
                                           0.9 * np.arange(6), 9),
        "kaleido5-no-inversion": kaleidoscope_cassi(rng.random((9, 11, 14)), 2.0 * np.arange(6),
                                                    5, inversion=False),
        "per-view-offsets": kaleidoscope_cassi(rng.random((3, 8, 10)),
                                               rng.uniform(-3, 3, (3, 4)), 3),
        "one-band": standard_cassi(rng.random((6, 7)), 1.5, 1),
        "one-row": standard_cassi(rng.random((1, 9)), 1.0, 3),
        "one-column": kaleidoscope_cassi(rng.random((3, 6, 1)), 0.5 * np.arange(3), 3),
    }


def warped_cassi(rng):
    """A two-view CASSI operator whose second view resamples (a sub-pixel translation)."""
    from recon.operators import CassiOperator, Translate, View

    return CassiOperator([View(rng.random((11, 14)), 0.7 * np.arange(4)),
                          View(rng.random((11, 14)), 0.5 * np.arange(4), Translate(0.3, 1.2))])
