r"""Richardson–Lucy deconvolution kernels: the two passes of one iteration.

With the observed image :math:`d`, the estimate :math:`u` and the point-spread function
:math:`k` (odd size :math:`m = 2n+1`, zero outside the image, ``'same'`` centring):

.. math::

    r = d \,/\, (k * u + \epsilon), \qquad u \leftarrow u \odot (k^\flat * r),

with :math:`k^\flat` the PSF mirrored, exactly as ``skimage.restoration.richardson_lucy``
(:func:`recon.calibration.mask.deconvolve` keeps that call as the reference these kernels are
tested against).  Both convolutions are written as correlations,
:math:`(k * u)[i, j] = \sum_{p,q} u[i+p-n, j+q-n]\, k^\flat[p, q]`, evaluated directly: for the
Airy kernels of the calibration (7×7 to 11×11) that is fewer operations than the FFTs that
``scipy.signal.convolve`` picks, and the inner loop, along a row, vectorises.  Each output row
is one task (it reads :math:`m` input rows); the first pass writes :math:`r`, the second
updates :math:`u` in place (it reads only :math:`r`), so rows run in parallel in both.

The calibration deconvolves the mask images of every view and band (130 crops for five
``paper`` views); figures in ``docs/speed_product.md``.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["ratio", "update"]


@jit(refcount=False)
def _correlate_row(a, k, i, acc):
    r"""``acc`` :math:`= \sum_{p,q} a[i+p-n, j+q-n]\, k[p, q]` for every column ``j`` of row
    ``i`` (zero outside ``a``)."""
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
def ratio(u, d, kflip, eps, out):
    r"""``out`` :math:`= d / (k * u + \epsilon)`, with ``kflip`` :math:`= k^\flat` (the
    convolution with :math:`k` is the correlation with its mirror image).

    Parameters
    ----------
    u, d : ndarray, shape (h, w)
        Estimate and observed image (float32, like the kernel and ``out``).
    kflip : ndarray, shape (m, m)
    eps : float
    out : ndarray, shape (h, w)
        Must not be ``u``.
    """
    h, w = u.shape
    for i in prange(h):
        acc = np.empty(w, dtype=out.dtype)
        _correlate_row(u, kflip, i, acc)
        di, oi = d[i], out[i]
        for j in range(w):
            oi[j] = di[j] / (acc[j] + eps)


@jit(parallel=True)
def update(u, r, k):
    r"""``u`` :math:`\mathrel{\odot}= k^\flat * r`, i.e. ``u`` times the correlation of ``r``
    with ``k`` (the convolution with the mirrored PSF)."""
    h, w = u.shape
    for i in prange(h):
        acc = np.empty(w, dtype=u.dtype)
        _correlate_row(r, k, i, acc)
        ui = u[i]
        for j in range(w):
            ui[j] *= acc[j]
