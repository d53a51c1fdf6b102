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


#: Pixels of a run whose products a tile of :func:`gram` sums in the working precision
#: before it adds them to its float64 sums.
_RUN = 512


@jit(refcount=False)
def _put(acc, a, b, s):
    """``acc[a, b] += s`` where (a, b) is an entry of the lower triangle."""
    n = acc.shape[0]
    if a < n and b <= a:
        acc[a, b] += s


@jit(refcount=False)
def _gram_tile(v, a0, b0, r0, r1, acc):
    r"""The 4 × 4 entries (a0 .. a0+3, b0 .. b0+3) of :math:`v v^\top` over pixels
    ``r0 .. r1 - 1``, summed in ``v``'s precision and added to ``acc`` (float64; the lower
    triangle only).  Rows past the last band repeat the last one and are not added: every
    pixel's eight values are loaded once for sixteen products, where a pair at a time loads
    two for one."""
    last = v.shape[0] - 1
    x0, x1 = v[a0, r0:r1], v[min(a0 + 1, last), r0:r1]
    x2, x3 = v[min(a0 + 2, last), r0:r1], v[min(a0 + 3, last), r0:r1]
    y0, y1 = v[b0, r0:r1], v[min(b0 + 1, last), r0:r1]
    y2, y3 = v[min(b0 + 2, last), r0:r1], v[min(b0 + 3, last), r0:r1]
    z = v.dtype.type(0)
    s00 = s01 = s02 = s03 = s10 = s11 = s12 = s13 = z
    s20 = s21 = s22 = s23 = s30 = s31 = s32 = s33 = z
    for i in range(r1 - r0):
        p0, p1, p2, p3 = x0[i], x1[i], x2[i], x3[i]
        q0, q1, q2, q3 = y0[i], y1[i], y2[i], y3[i]
        s00 += p0 * q0
        s01 += p0 * q1
        s02 += p0 * q2
        s03 += p0 * q3
        s10 += p1 * q0
        s11 += p1 * q1
        s12 += p1 * q2
        s13 += p1 * q3
        s20 += p2 * q0
        s21 += p2 * q1
        s22 += p2 * q2
        s23 += p2 * q3
        s30 += p3 * q0
        s31 += p3 * q1
        s32 += p3 * q2
        s33 += p3 * q3
    _put(acc, a0, b0, s00)
    _put(acc, a0, b0 + 1, s01)
    _put(acc, a0, b0 + 2, s02)
    _put(acc, a0, b0 + 3, s03)
    _put(acc, a0 + 1, b0, s10)
    _put(acc, a0 + 1, b0 + 1, s11)
    _put(acc, a0 + 1, b0 + 2, s12)
    _put(acc, a0 + 1, b0 + 3, s13)
    _put(acc, a0 + 2, b0, s20)
    _put(acc, a0 + 2, b0 + 1, s21)
    _put(acc, a0 + 2, b0 + 2, s22)
    _put(acc, a0 + 2, b0 + 3, s23)
    _put(acc, a0 + 3, b0, s30)
    _put(acc, a0 + 3, b0 + 1, s31)
    _put(acc, a0 + 3, b0 + 2, s32)
    _put(acc, a0 + 3, b0 + 3, s33)


@jit(parallel=True)
def gram(v, partial):
    r"""Partial Gram matrices :math:`\sum_{n \in b} v_{:,n} v_{:,n}^\top` of each pixel block
    :math:`b` into ``partial`` (``(blocks, L, L)`` float64; the caller sums them in order).
    ``v``: ``(L, N)`` float32, contiguous.

    Within a block, runs of :data:`_RUN` pixels are summed in ``v``'s precision by tiles of
    4 × 4 band pairs (:func:`_gram_tile`) and the runs in float64: the error is that of a
    512-term float32 sum, about :math:`10^{-7}` of the entries, far below what moves a
    leading eigenvector."""
    n_bands, n = v.shape
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        acc = partial[blk]
        acc[:, :] = 0.0
        for r0 in range(lo, hi, _RUN):
            r1 = min(hi, r0 + _RUN)
            for a0 in range(0, n_bands, 4):
                for b0 in range(0, a0 + 1, 4):
                    _gram_tile(v, a0, b0, r0, r1, acc)
        for a in range(n_bands):
            for b in range(a):
                acc[b, a] = acc[a, b]


@jit(refcount=False)
def _mix_tile(c, src, d0, d1, d2, d3, p0, r0, r1):
    r"""Rows ``p0 .. p0+3`` of :math:`C\,\mathrm{src}` on pixels ``r0 .. r1 - 1`` into
    ``d0 .. d3`` (rows past the last of ``c`` repeat it; their ``d`` is the caller's scratch),
    four source rows at a time: each pass over the run loads four source values and updates
    four outputs with them, where a source row at a time loads and stores an output for each
    product."""
    p_rows, q_rows = c.shape
    last = p_rows - 1
    m = r1 - r0
    for i in range(m):
        d0[i] = 0
        d1[i] = 0
        d2[i] = 0
        d3[i] = 0
    pa, pb, pc, pd = p0, min(p0 + 1, last), min(p0 + 2, last), min(p0 + 3, last)
    q = 0
    while q + 4 <= q_rows:
        a0, a1, a2, a3 = c[pa, q], c[pa, q + 1], c[pa, q + 2], c[pa, q + 3]
        b0, b1, b2, b3 = c[pb, q], c[pb, q + 1], c[pb, q + 2], c[pb, q + 3]
        e0, e1, e2, e3 = c[pc, q], c[pc, q + 1], c[pc, q + 2], c[pc, q + 3]
        f0, f1, f2, f3 = c[pd, q], c[pd, q + 1], c[pd, q + 2], c[pd, q + 3]
        s0, s1 = src[q, r0:r1], src[q + 1, r0:r1]
        s2, s3 = src[q + 2, r0:r1], src[q + 3, r0:r1]
        for i in range(m):
            x0, x1, x2, x3 = s0[i], s1[i], s2[i], s3[i]
            d0[i] += a0 * x0 + a1 * x1 + a2 * x2 + a3 * x3
            d1[i] += b0 * x0 + b1 * x1 + b2 * x2 + b3 * x3
            d2[i] += e0 * x0 + e1 * x1 + e2 * x2 + e3 * x3
            d3[i] += f0 * x0 + f1 * x1 + f2 * x2 + f3 * x3
        q += 4
    while q < q_rows:
        a0, b0, e0, f0 = c[pa, q], c[pb, q], c[pc, q], c[pd, q]
        s0 = src[q, r0:r1]
        for i in range(m):
            x0 = s0[i]
            d0[i] += a0 * x0
            d1[i] += b0 * x0
            d2[i] += e0 * x0
            d3[i] += f0 * x0
        q += 1


@jit(parallel=True)
def mix(c, src, dst):
    r""":math:`\mathrm{dst} = C\,\mathrm{src}`: ``c`` ``(P, Q)``, ``src`` ``(Q, N)``, ``dst``
    ``(P, N)``, float32 (``dst`` may not alias ``src``).  The projection is ``c`` =
    :math:`E^\top` (C-contiguous), the expansion ``c`` = :math:`E`.

    Runs of :data:`_RUN` pixels, four rows of ``dst`` at a time (:func:`_mix_tile`; the rows
    past the last go to a scratch): the run's outputs stay in the core's first cache while
    the source rows stream through it."""
    p_rows, n = dst.shape
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo = blk * _BLOCK
        hi = min(n, lo + _BLOCK)
        spare = np.empty((3, _RUN), dtype=dst.dtype)
        for r0 in range(lo, hi, _RUN):
            r1 = min(hi, r0 + _RUN)
            m = r1 - r0
            for p0 in range(0, p_rows, 4):
                d1 = dst[p0 + 1, r0:r1] if p0 + 1 < p_rows else spare[0, :m]
                d2 = dst[p0 + 2, r0:r1] if p0 + 2 < p_rows else spare[1, :m]
                d3 = dst[p0 + 3, r0:r1] if p0 + 3 < p_rows else spare[2, :m]
                _mix_tile(c, src, dst[p0, r0:r1], d1, d2, d3, p0, r0, r1)


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
