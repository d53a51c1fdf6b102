r"""The sensor's point-spread function on a stack of views, as a direct correlation.

For a (K, H, W) stack :math:`y`, a (m, m) weight array :math:`F` (:math:`m = 2n + 1`) and a
scale :math:`s`,

.. math::

    \mathrm{out}[k, i, j] = s \sum_{a=0}^{m-1} \sum_{b=0}^{m-1} F[a, b]\;
        y[k,\, i + a - n,\, j + b - n],

with :math:`y` zero outside each view.  This is the correlation with :math:`F`; the
convolution :math:`P * y` of :class:`~recon.operators.blur.BlurredOperator` is the
correlation with the mirrored kernel :math:`F = P^\flat`, and its adjoint (correlation with
:math:`P`) is the correlation with :math:`F = P`.  The scale folds the operator's row scaling
(:class:`~recon.operators.base.ScaledOperator`) into the same pass.

One output row is a task: its :math:`m` source rows are read from cache, the row is summed in
a float32 accumulator (contiguous slices, so LLVM vectorises the inner loop) and written once,
so the stack is read and written once.  The FFT of
:func:`recon.operators.blur.convolve_views` is the tested reference; the two differ only by
rounding (float32 accumulation of :math:`m^2` terms against the FFT's round-off).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["correlate_views", "correlate_row"]

#: Output rows per parallel task (one accumulator allocated per task).
_ROWS = 8


@jit(refcount=False)
def correlate_row(a, k, i, acc):
    r"""``acc`` :math:`= \sum_{p,q} a[i+p-n, j+q-n]\, k[p, q]` for every column ``j`` of row
    ``i`` of the image ``a`` (H, W), zero outside ``a``; ``k`` is (m, m), m = 2n + 1.  The row
    kernel of :func:`correlate_views` and of :mod:`recon.kernels.deconvolve`.

    The taps of a kernel row go four to a pass over the row where all four fall inside it
    (``acc`` loaded and stored once for four products, not once for each), in the order
    :math:`(p, q)` every column adds them in one at a time: the same sums, the same bits."""
    h, w = a.shape
    m = k.shape[0]
    n = m // 2
    for j in range(w):
        acc[j] = 0
    for p in range(m):
        ii = i + p - n
        if ii < 0 or ii >= h:
            continue
        src = a[ii]
        q = 0
        while q + 4 <= m:
            # Columns j where taps q .. q + 3 all lie inside the row.
            lo = max(0, n - q)
            hi = min(w, w + n - q - 3)
            if hi > lo:
                _edge_taps(src, k, p, q, 4, 0, lo, acc)
                k0, k1, k2, k3 = k[p, q], k[p, q + 1], k[p, q + 2], k[p, q + 3]
                d = acc[lo:hi]
                s0, s1 = src[lo + q - n:hi + q - n], src[lo + q + 1 - n:hi + q + 1 - n]
                s2, s3 = src[lo + q + 2 - n:hi + q + 2 - n], src[lo + q + 3 - n:hi + q + 3 - n]
                for j in range(hi - lo):
                    d[j] = d[j] + k0 * s0[j] + k1 * s1[j] + k2 * s2[j] + k3 * s3[j]
                _edge_taps(src, k, p, q, 4, hi, w, acc)
            else:
                _edge_taps(src, k, p, q, 4, 0, w, acc)
            q += 4
        while q < m:
            kq = k[p, q]
            # Columns j whose tap j + q - n lies inside the row.
            lo = max(0, n - q)
            hi = min(w, w + n - q)
            if hi > lo:
                d, s = acc[lo:hi], src[lo + q - n:hi + q - n]
                for j in range(hi - lo):
                    d[j] += kq * s[j]
            q += 1


@jit(refcount=False)
def _edge_taps(src, k, p, q0, g, j0, j1, acc):
    """``acc[j]`` += the taps ``q0 .. q0 + g - 1`` of kernel row ``p`` that lie inside the
    row, one at a time in that order, for the columns ``j0 .. j1 - 1`` (the few at either
    end that :func:`correlate_row` cannot give all of a group's taps)."""
    w = src.shape[0]
    n = k.shape[0] // 2
    for j in range(j0, j1):
        for q in range(q0, q0 + g):
            c = j + q - n
            if 0 <= c < w:
                acc[j] += k[p, q] * src[c]


@jit(parallel=True)
def correlate_views(y, f, scale, out):
    r"""``out`` :math:`= s\,(F \star y_k)` for every view ``k`` (see the module docstring).

    Parameters
    ----------
    y : ndarray, shape (K, H, W), float32, C-contiguous
    f : ndarray, shape (m, m), m odd, same precision
    scale : float
        :math:`s`, in the working precision.
    out : ndarray, shape (K, H, W)
        Must not be ``y``.
    """
    k_, h, w = y.shape
    per_view = (h + _ROWS - 1) // _ROWS
    for task in prange(k_ * per_view):
        k = task // per_view
        i0 = (task - k * per_view) * _ROWS
        acc = np.empty(w, dtype=out.dtype)
        for i in range(i0, min(h, i0 + _ROWS)):
            correlate_row(y[k], f, i, acc)
            row = out[k, i]
            for j in range(w):
                row[j] = scale * acc[j]
