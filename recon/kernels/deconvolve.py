r"""Deconvolution kernels: the two passes of a Richardson–Lucy iteration, and the element-wise
passes of the TV deconvolution's FISTA steps.

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

The TV deconvolution (:func:`recon.calibration.mask.tv_deconvolve`) takes each FISTA step in
the Fourier domain; between its transforms, :func:`residual_spectrum`, :func:`residual` and
:func:`momentum` are its NumPy expressions as threaded passes, compiled without fast-math
(``jit(exact=True)``): the same operations in the same order, so the same bits.

The calibration deconvolves the mask images of every view and band (130 crops for five
``paper`` views); figures in ``docs/speed_product.md``.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit
from recon.kernels.blur import correlate_row

__all__ = ["ratio", "update", "residual_spectrum", "residual", "momentum"]

#: Elements per parallel task of the element-wise passes.
_BLOCK = 1 << 14


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


@jit(parallel=True, exact=True)
def residual_spectrum(spec, power, kd):
    r"""``spec`` :math:`\leftarrow \hat z\,|\hat k|^2 - \hat k^* \hat d` in place, as NumPy's
    ``spec *= power; spec -= kd`` computes it (a complex times a real promoted to complex:
    :math:`(a + ib)(p + 0i) = (ap - b\cdot 0) + i(a\cdot 0 + bp)`).

    Parameters
    ----------
    spec, kd : ndarray, shape (2n,)
        Complex spectra as their float32 (real, imaginary) pairs.
    power : ndarray, shape (n,)
    """
    n = power.shape[0]
    zero = power.dtype.type(0)
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        # Each task on slices of its own: a loop over the whole arrays' indices between
        # bounds does not vectorise.
        lo, hi = blk * _BLOCK, min(n, (blk + 1) * _BLOCK)
        sp, p, k = spec[2 * lo:2 * hi], power[lo:hi], kd[2 * lo:2 * hi]
        for i in range(hi - lo):
            a, b = sp[2 * i], sp[2 * i + 1]
            sp[2 * i] = (a * p[i] - b * zero) - k[2 * i]
            sp[2 * i + 1] = (a * zero + b * p[i]) - k[2 * i + 1]


@jit(parallel=True, exact=True)
def residual(z, r, s, out):
    r"""``out`` :math:`= z - s\,r`, as NumPy's ``r *= s; out = z - r`` (``r`` is left as it
    was); flat arrays of one size."""
    n = z.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo, hi = blk * _BLOCK, min(n, (blk + 1) * _BLOCK)
        zz, rr, oo = z[lo:hi], r[lo:hi], out[lo:hi]
        for i in range(hi - lo):
            oo[i] = zz[i] - rr[i] * s


@jit(parallel=True, exact=True)
def momentum(nxt, u, c, z):
    r"""``z`` :math:`= (x_{k+1} - x_k)\,c + x_{k+1}` (``nxt``, ``u``), as NumPy's
    ``z = nxt - u; z *= c; z += nxt``; flat arrays of one size."""
    n = z.shape[0]
    for blk in prange((n + _BLOCK - 1) // _BLOCK):
        lo, hi = blk * _BLOCK, min(n, (blk + 1) * _BLOCK)
        a, b, o = nxt[lo:hi], u[lo:hi], z[lo:hi]
        for i in range(hi - lo):
            o[i] = (a[i] - b[i]) * c + a[i]
