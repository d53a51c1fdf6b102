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
from recon.kernels.blur import correlate_row

__all__ = ["ratio", "update"]


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
        correlate_row(u, kflip, i, acc)
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
        correlate_row(r, k, i, acc)
        ui = u[i]
        for j in range(w):
            ui[j] *= acc[j]
