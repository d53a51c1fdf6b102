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
    kernel of :func:`correlate_views` and of :mod:`recon.kernels.deconvolve`."""
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
        for q in range(m):
            kq = k[p, q]
            # Columns j whose tap j + q - n lies inside the row.
            lo = max(0, n - q)
            hi = min(w, w + n - q)
            if hi <= lo:
                continue
            d, s = acc[lo:hi], src[lo + q - n:hi + q - n]
            for j in range(hi - lo):
                d[j] += kq * s[j]


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
