r"""Element-wise passes of the mask images' TV deconvolution
(:func:`recon.calibration.mask.tv_deconvolve`), fused and threaded.

Every FISTA step of that deconvolution, on the padded crops of a chunk of bands, makes the
data term's gradient in the Fourier domain and the momentum in the image domain:

.. math::

    \hat s \leftarrow |\hat k|^2 \hat s - \hat k^* \hat d, \qquad
    z \leftarrow (u_{k} - u_{k-1})\,c + u_{k},

which NumPy does in two and three whole-array passes.  Here each is one pass, spread over the
rows on Numba's threads.  These kernels are compiled **without** fast-math: every element is
rounded as NumPy's sequence of operations rounds it (no fused multiply-add, no reassociation),
so the deconvolved mask images, and the calibration, stay the same to the bit; the tests
compare them with the NumPy expressions they replace.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["spectral_step", "momentum"]


@njit(cache=True, parallel=True, nogil=True)
def spectral_step(spec, power, kd):
    r"""``spec`` :math:`\leftarrow` ``spec * power - kd`` in place (complex64 ``spec``, ``kd``;
    float32 ``power``; all ``(n, h, w)``), as ``spec *= power; spec -= kd``: the real factor
    scales both parts, each part then minus ``kd``'s."""
    n, h, w = spec.shape
    for r in prange(n * h):
        b, i = r // h, r % h
        s, p, k = spec[b, i], power[b, i], kd[b, i]
        for j in range(w):
            pr = p[j]
            re = s[j].real * pr
            im = s[j].imag * pr
            s[j] = complex(re - k[j].real, im - k[j].imag)


@njit(cache=True, parallel=True, nogil=True)
def momentum(new, old, c, out):
    r"""``out`` :math:`= (\mathrm{new} - \mathrm{old})\,c + \mathrm{new}` (float32, ``(n, h, w)``),
    as ``np.subtract(new, old, out=out); out *= c; out += new``; ``out`` may be ``old``."""
    n, h, w = out.shape
    for r in prange(n * h):
        b, i = r // h, r % h
        a, o, z = new[b, i], old[b, i], out[b, i]
        for j in range(w):
            d = a[j] - o[j]
            d = d * c
            z[j] = d + a[j]
