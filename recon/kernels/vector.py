r"""Element-wise combinations of whole cubes in one pass (the solvers' vector updates).

NumPy evaluates :math:`a u + b v + c w` as five passes with a temporary; these kernels read
each input once and write the output once, split into contiguous blocks over threads (each
element is computed the same way whatever the split, so results do not depend on threads).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["combine3", "diff_dot", "diff_sq", "extrapolate", "momentum_pass", "blocks",
           "squared_distance"]

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
def diff_dot(a, b, c, partial):
    r"""Block sums of :math:`(a-b)\cdot(b-c)` into ``partial`` (float64, one per block of
    ``_BLOCK`` elements; the caller sums them in order, so the result does not depend on the
    threads).  FISTA's restart test without storing either difference."""
    n = a.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        aa, bb, cc = a[lo:hi], b[lo:hi], c[lo:hi]
        acc = 0.0
        for i in range(hi - lo):
            acc += (aa[i] - bb[i]) * (bb[i] - cc[i])
        partial[blk] = acc


@jit(parallel=True)
def diff_sq(a, b, partial):
    r"""Block sums of :math:`(a-b)^2` into ``partial`` (float64, one per block; each
    difference taken in float64, as NumPy does on the float64 copies it replaces)."""
    n = a.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        aa, bb = a[lo:hi], b[lo:hi]
        acc = 0.0
        for i in range(hi - lo):
            d = np.float64(aa[i]) - np.float64(bb[i])
            acc += d * d
        partial[blk] = acc


def squared_distance(a, b, threads=None) -> float:
    r""":math:`\sum (a-b)^2` of two float32 C-contiguous arrays of one shape, in one pass
    (float64 sums per block, added in order: the result does not depend on the threads)."""
    from recon import kernels

    a, b = a.reshape(-1), b.reshape(-1)
    partial = np.empty(blocks(a.size), dtype=np.float64)
    with kernels.threads(threads):
        diff_sq(a, b, partial)
    return float(partial.sum())


@jit(parallel=True)
def extrapolate(f, f_prev, beta, out):
    r"""``out`` :math:`= f + \beta (f - f_\mathrm{prev})` (FISTA's momentum step)."""
    n = out.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        o, ff, pp = out[lo:hi], f[lo:hi], f_prev[lo:hi]
        for i in range(hi - lo):
            o[i] = ff[i] + beta * (ff[i] - pp[i])


@jit(parallel=True)
def momentum_pass(z, f, f_prev, beta, dot, change, size):
    r"""FISTA's three vector updates after the prox, in one pass over ``(L, N)`` cubes.

    For every band :math:`l` and block of ``_BLOCK`` elements (task ``l * nb + j``, ``nb``
    blocks a band) it sums, in float64,

    * ``dot`` :math:`\mathrel{+}= (z-f)\cdot(f-f_\mathrm{prev})` (the restart test's inner
      product, taken with the old ``z``),
    * ``change`` :math:`\mathrel{+}= \|f-f_\mathrm{prev}\|^2` and ``size``
      :math:`\mathrel{+}= \|f_\mathrm{prev}\|^2` (the stopping rule's relative change),

    then writes ``z`` :math:`= f + \beta (f - f_\mathrm{prev})` (the momentum step).  The
    blocks are a band's own, so a caller weighs each band's sums (the band metric) and adds
    them in a fixed order: the result does not depend on the threads.
    """
    n_bands, n = f.shape
    nb = (n + _BLOCK - 1) // _BLOCK
    for task in prange(n_bands * nb):
        band = task // nb
        lo = (task - band * nb) * _BLOCK
        hi = min(n, lo + _BLOCK)
        zz, ff, pp = z[band, lo:hi], f[band, lo:hi], f_prev[band, lo:hi]
        a = 0.0
        c = 0.0
        s = 0.0
        for i in range(hi - lo):
            fi = ff[i]
            pi = pp[i]
            d = fi - pi
            a += (zz[i] - fi) * d
            c += np.float64(d) * np.float64(d)
            s += np.float64(pi) * np.float64(pi)
            zz[i] = fi + beta * d
        dot[task] = a
        change[task] = c
        size[task] = s


def blocks(n: int) -> int:
    """Number of blocks (and of partial sums) for ``n`` elements."""
    return (n + _BLOCK - 1) // _BLOCK
