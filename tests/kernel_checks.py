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
