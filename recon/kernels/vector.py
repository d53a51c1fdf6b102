r"""Element-wise combinations of whole cubes in one pass (the solvers' vector updates).

NumPy evaluates :math:`a u + b v + c w` as five passes with a temporary; these kernels read
each input once and write the output once, split into contiguous blocks over threads (each
element is computed the same way whatever the split, so results do not depend on threads).
"""

from __future__ import annotations

from numba import prange

from recon.kernels import jit

__all__ = ["combine3", "axpy"]

#: Elements per parallel block.
_BLOCK = 1 << 15


@jit(parallel=True)
def combine3(a, u, b, v, c, w, out):
    r"""``out`` :math:`= a u + b v + c w` for flat (1-D, contiguous) arrays.

    ``out`` may alias any input (each element is read before it is written).  The weights
    are given in the arrays' precision.
    """
    n = out.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        o, uu, vv, ww = out[lo:hi], u[lo:hi], v[lo:hi], w[lo:hi]
        for i in range(hi - lo):
            o[i] = a * uu[i] + b * vv[i] + c * ww[i]


@jit(parallel=True)
def axpy(x, a, y, out):
    r"""``out`` :math:`= x + a y` for flat (1-D, contiguous) arrays; ``out`` may alias."""
    n = out.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        o, xx, yy = out[lo:hi], x[lo:hi], y[lo:hi]
        for i in range(hi - lo):
            o[i] = xx[i] + a * yy[i]
