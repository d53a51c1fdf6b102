r"""The sensor's point-spread function after a multi-view CASSI model.

The imaging lens blurs what reaches the sensor: the coded, dispersed image of every band, so
the blur acts after the mask and the prism, on the measurement,

.. math::

    g_k = P * \Big(\sum_l C_{k,l} \odot S_{k,l}\big(W_k f_l\big)\Big) = (P * H_k) f,

with :math:`P` the point-spread function (odd size :math:`m = 2n + 1`, centred, zero beyond
each view's box) and :math:`H` a calibrated model whose mask images are the *deconvolved*
captures (:func:`recon.calibration.mask.deconvolve`).  The Airy radius grows with wavelength,
but each band's PSF could only act on that band's own part of the sum; on the ``paper`` design
(1.35–2.11 px over 26 bands) one PSF at the bands' mean radius leaves the same model error
‖g − sHf‖/‖g‖ as 26 (noise-free frame of ``natural``: 2.65 % against 2.62 % with one view,
3.77 % against 3.75 % with five; 6.80 % and 7.28 % without any blur), so the blur is one
convolution per view after the sum.  (A mask that varies from pixel to pixel does not
commute with a convolution: blurring the mask images instead is another, approximate model.)

The adjoint is the correlation with the same kernel: for an odd centred kernel in ``'same'``
mode, :math:`\langle P * y, z\rangle = \langle y, P^\flat * z\rangle`, :math:`P^\flat` the
kernel mirrored.

Measurement rows share pixels of the coded image, so :math:`HH^\top` is not diagonal: the
operator gives the mean squared row norm (:meth:`BlurredOperator.mean_row_norm_sq`,
Hutchinson's estimator), which is all the row scaling needs, and no per-row norms (GAP-TV's
diagonal projection would be inexact and is refused).
"""

from __future__ import annotations

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.operators.dispersion import work_dtype

#: Rademacher probes of :meth:`BlurredOperator.mean_row_norm_sq` (fixed seed).
NORM_PROBES = 4


def check_kernel(kernel) -> np.ndarray:
    """``kernel`` as a (m, m) float32 array, ``m`` odd, finite, non-negative, not all zero."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.ndim != 2 or k.shape[0] != k.shape[1] or k.shape[0] % 2 != 1:
        raise InputError(f"a point-spread function must be square with an odd size, got shape "
                         f"{k.shape}")
    if not np.all(np.isfinite(k)) or np.any(k < 0) or not k.sum() > 0:
        raise InputError("a point-spread function must be finite, non-negative and not zero")
    return k.astype(np.float32)


def convolve_views(y: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    r""":math:`P * y_k` for every view ``k`` of a (K, H, W) stack, zero outside each view,
    ``'same'`` size (the dtype of ``y`` is kept).

    A float32 stack goes through the direct correlation with the mirrored kernel
    (:func:`recon.kernels.blur.correlate_views`: one pass, threads) where the kernels run;
    the FFT (:func:`scipy.signal.fftconvolve`) is the reference and the path for float64.
    """
    if kernels.usable(y, kernel):
        from recon.kernels import blur as kblur

        src = np.ascontiguousarray(y)
        out = np.empty_like(src)
        with kernels.threads():
            kblur.correlate_views(src, np.ascontiguousarray(kernel[::-1, ::-1]),
                                  np.float32(1.0), out)
        return out
    from scipy.signal import fftconvolve

    out = fftconvolve(y, kernel[None].astype(y.dtype, copy=False), mode="same", axes=(1, 2))
    return out.astype(y.dtype, copy=False)


class BlurredOperator(LinearOperator):
    r""":math:`y = P * (A x)`: any operator onto (K, H, W) view stacks, then one point-spread
    function on every view (see the module notes).

    Parameters
    ----------
    op : LinearOperator
        The unblurred model :math:`A`, ``oshape`` (K, H, W).
    kernel : (m, m) array_like
        :math:`P`, ``m`` odd; it is used as given (normalise it to sum 1 to keep the
        radiometry).

    Attributes
    ----------
    op : LinearOperator
    kernel : (m, m) float32
    """

    def __init__(self, op: LinearOperator, kernel):
        if len(op.oshape) != 3:
            raise InputError(f"the blurred operator needs (K, H, W) measurements, got "
                             f"{op.oshape}")
        self.op = op
        self.kernel = check_kernel(kernel)
        self._flipped = np.ascontiguousarray(self.kernel[::-1, ::-1])
        self._mean_rn = None
        super().__init__(op.ishape, op.oshape)

    def _forward(self, x):
        return convolve_views(self.op.forward(x), self.kernel)

    def _adjoint(self, y):
        return self.op.adjoint(convolve_views(y, self._flipped))

    def adjoint_add(self, y, base, scale=1.0, out=None, base_weights=None):
        # The inner operator's own (fused) gradient step, on the correlated measurement.
        y = np.asarray(y)
        if y.shape != self.oshape:
            raise ValueError(f"{type(self).__name__}: input shape {y.shape} != {self.oshape}")
        return self.op.adjoint_add(convolve_views(y, self._flipped), base, scale, out,
                                   base_weights=base_weights)

    def band_forward(self, band: int, image) -> np.ndarray:
        r""":math:`P * (A f)` for the cube that is ``image`` in band ``band`` and zero
        elsewhere, through the inner operator's ``band_forward`` where it has one (the
        blur is the same; see :meth:`CalibratedCassi.band_forward
        <recon.operators.calibrated.CalibratedCassi.band_forward>`), else the full forward."""
        inner = getattr(self.op, "band_forward", None)
        if inner is None:
            x = np.zeros(self.ishape, dtype=work_dtype(np.asarray(image)))
            x[band] = image
            return self.forward(x)
        return convolve_views(inner(band, image), self.kernel)

    def mean_row_norm_sq(self) -> float:
        r"""Mean of :math:`\|a_i\|^2` over the rows with any weight: :math:`\|A\|_F^2 / n` by
        Hutchinson's estimator, :math:`\mathbb E\|Az\|^2` over :data:`NORM_PROBES` Rademacher
        probes :math:`z` (fixed seed, so a reconstruction is reproducible).  The rows with
        weight are those :math:`A\mathbf 1` reaches (above the FFT's round-off)."""
        if self._mean_rn is None:
            reach = self.forward(np.ones(self.ishape, np.float32))
            n = int(np.count_nonzero(reach > 1e-6 * float(reach.max()))) if reach.max() > 0 else 0
            from recon.probes import rademacher

            rng = np.random.default_rng(0)
            acc = 0.0
            z = np.empty(self.ishape, np.float32)
            for _ in range(NORM_PROBES):
                rademacher(rng, self.ishape, out=z)
                acc += float(np.sum(self.forward(z).astype(np.float64) ** 2))
            self._mean_rn = acc / NORM_PROBES / max(n, 1)
        return self._mean_rn

    def row_norms_sq(self):
        raise NotImplementedError(
            "the blurred model's measurement rows share pixels: it has no per-row norms "
            "(use fista-tv or twist, not gap-tv)")

    def __repr__(self):
        m = self.kernel.shape[0]
        return f"<BlurredOperator {m}×{m} PSF after {self.op!r}>"
