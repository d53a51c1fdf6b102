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

__all__ = ["correlate_views"]

#: Output rows per parallel task (one accumulator allocated per task).
_ROWS = 8


@jit(refcount=False)
def _correlate_row(y, f, i, scale, acc, out):
    """``out`` = ``scale`` × the correlation of ``y`` (H, W) with ``f`` on row ``i``."""
    h, w = y.shape
    m = f.shape[0]
    n = m // 2
    for j in range(w):
        acc[j] = 0
    for a in range(m):
        r = i + a - n
        if r < 0 or r >= h:
            continue
        src = y[r]
        for b in range(m):
            wgt = f[a, b]
            d = b - n
            # Columns j with 0 <= j + d < w.
            j0 = max(0, -d)
            j1 = min(w, w - d)
            o = acc[j0:j1]
            s = src[j0 + d:j1 + d]
            for j in range(j1 - j0):
                o[j] += wgt * s[j]
    for j in range(w):
        out[j] = scale * acc[j]


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
            _correlate_row(y[k], f, i, scale, acc, out[k, i])
