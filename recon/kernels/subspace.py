r"""Kernels of the spectral subspace priors (:mod:`recon.priors.subspace`).

The band Gram matrix :math:`v v^\top` of an ``(L, N)`` cube, the projection
:math:`z = E^\top v` on an orthonormal basis :math:`E` (``L × k``), the expansion
:math:`x = E z`, and the eigenvectors of a small symmetric matrix (cyclic Jacobi).  Each is a
small product that BLAS would do in a few milliseconds, but BLAS threads spin on a machine
whose cores are busy (docs/priors.md): here they are blocks over pixels on Numba's threads, and the Gram's
partial sums are added in block order, so the result does not depend on the threads.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["gram", "mix", "jacobi_eigh", "blocks"]

#: Pixels per parallel block.
_BLOCK = 4096


def blocks(n: int) -> int:
    """Number of pixel blocks (and of partial Gram matrices) for ``n`` pixels."""
    return (n + _BLOCK - 1) // _BLOCK


@jit(parallel=True)
def gram(v, partial):
    r"""Partial Gram matrices :math:`\sum_{n \in b} v_{:,n} v_{:,n}^\top` of each pixel block
    :math:`b` into ``partial`` (``(blocks, L, L)`` float64; the caller sums them in order).
    ``v``: ``(L, N)`` float32, contiguous."""
    n_bands, n = v.shape
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        acc = partial[blk]
        for a in range(n_bands):
            va = v[a, lo:hi]
            for b in range(a + 1):
                vb = v[b, lo:hi]
                s = 0.0
                for i in range(hi - lo):
                    s += va[i] * vb[i]
                acc[a, b] = s
                acc[b, a] = s


@jit(parallel=True)
def mix(c, src, dst):
    r""":math:`\mathrm{dst} = C\,\mathrm{src}`: ``c`` ``(P, Q)``, ``src`` ``(Q, N)``, ``dst``
    ``(P, N)``, float32 (``dst`` may not alias ``src``).  The projection is ``c`` =
    :math:`E^\top` (C-contiguous), the expansion ``c`` = :math:`E`."""
    p_rows, n = dst.shape
    q_rows = c.shape[1]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        for p in range(p_rows):
            dp = dst[p, lo:hi]
            dp[:] = 0
            for q in range(q_rows):
                w = c[p, q]
                sq = src[q, lo:hi]
                for i in range(hi - lo):
                    dp[i] += w * sq[i]


@jit()
def jacobi_eigh(a, tol, max_sweeps):
    r"""Eigenvalues and eigenvectors of a symmetric matrix by cyclic Jacobi rotations.

    ``a`` (``(L, L)`` float64) is overwritten.  Returns ``(w, v)``: ``w`` unsorted, ``v``'s
    columns the eigenvectors.  Stops when the off-diagonal norm falls below ``tol`` times the
    matrix's norm (or after ``max_sweeps`` sweeps).
    """
    n = a.shape[0]
    v = np.eye(n)
    total = 0.0
    for i in range(n):
        for j in range(n):
            total += a[i, j] * a[i, j]
    for _ in range(max_sweeps):
        off = 0.0
        for i in range(n):
            for j in range(i + 1, n):
                off += 2.0 * a[i, j] * a[i, j]
        if off <= tol * tol * total:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                if theta < 0:
                    t = -t
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for r in range(n):
                    arp, arq = a[r, p], a[r, q]
                    a[r, p] = c * arp - s * arq
                    a[r, q] = s * arp + c * arq
                for r in range(n):
                    apr, aqr = a[p, r], a[q, r]
                    a[p, r] = c * apr - s * aqr
                    a[q, r] = s * apr + c * aqr
                for r in range(n):
                    vrp, vrq = v[r, p], v[r, q]
                    v[r, p] = c * vrp - s * vrq
                    v[r, q] = s * vrp + c * vrq
    w = np.empty(n)
    for i in range(n):
        w[i] = a[i, i]
    return w, v
