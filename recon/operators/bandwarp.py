r"""Calibrated CASSI with its own geometric map per view *and band*.

:class:`~recon.operators.calibrated.CalibratedCassi` maps every band of a view through one warp
and then shifts it by the band's dispersion offset.  Through a prism the bands differ by more
than a shift: the anamorphic magnification and the direction of the dispersion change with the
wavelength (on the ``small`` design the left view's x-scale runs from 1.0385 at 450 nm to 1.0354
at 700 nm, and the top and bottom views shear by 3 %).  Here each band has its own map straight
into the view's box on the sensor,

.. math::

    g_k = \sum_l C_{k,l} \odot W_{k,l} f_l, \qquad
    f_l = \sum_k W_{k,l}^\top (C_{k,l} \odot g_k),

with :math:`C_{k,l}` the measured mask images (box coordinates) and :math:`W_{k,l}` bilinear
homography warps from the cube grid to the box.  The rows of :math:`H` that one sensor pixel
owns act on different bands, so :math:`\mathrm{diag}(HH^\top) = \sum_l C_{k,l}^2 \odot
\|W_{k,l}\|_\text{rows}^2` exactly.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.operators.dispersion import work_dtype
from recon.operators.mask import InPrecision, as_mask
from recon.operators.warp import HomographyWarp


class BandWarpCassi(LinearOperator):
    r"""Multi-view CASSI with a warp per view and band, ``(L, H, W) -> (K, Hv, Wm)``.

    Parameters
    ----------
    mask_images : (K, L, Hv, Wm) array_like
        :math:`C_{k,l}` in box coordinates.
    warps : K sequences of L :class:`~recon.operators.warp.HomographyWarp`
        :math:`W_{k,l}`, each from the cube grid ``(H, W)`` to the box ``(Hv, Wm)``; all with
        the same input shape.

    Attributes
    ----------
    mask_images : (K, L, Hv, Wm) float32
    warps : list of lists of HomographyWarp
    n_views, n_bands : int
    """

    def __init__(self, mask_images, warps):
        self.mask_images = as_mask(mask_images, name="mask_images", ndim=4)
        k, n_bands, hv, wm = self.mask_images.shape
        rows = [list(r) for r in warps]
        if len(rows) != k or any(len(r) != n_bands for r in rows):
            raise InputError(f"warps must be {k} views x {n_bands} bands, got "
                             f"{[len(r) for r in rows]}")
        in_shape = None
        for i, r in enumerate(rows):
            for l, w in enumerate(r):
                if not isinstance(w, HomographyWarp):
                    raise InputError(f"warps[{i}][{l}] must be a HomographyWarp, got "
                                     f"{type(w).__name__}")
                if w.out_shape != (hv, wm):
                    raise InputError(f"warps[{i}][{l}] maps to {w.out_shape}, the mask images "
                                     f"are {(hv, wm)}")
                in_shape = in_shape or w.in_shape
                if w.in_shape != in_shape:
                    raise InputError(f"warps[{i}][{l}] reads a {w.in_shape} grid, others "
                                     f"{in_shape}")
        self.warps = rows
        self.n_views, self.n_bands = k, n_bands
        self._masks = InPrecision(self.mask_images)
        super().__init__((n_bands,) + tuple(in_shape), (k, hv, wm))

    def _forward(self, x):
        dt = work_dtype(x)
        c = self._masks(dt)
        out = np.zeros(self.oshape, dtype=dt)
        for k, row in enumerate(self.warps):
            for l, w in enumerate(row):
                out[k] += c[k, l] * w.apply(x[l].astype(dt, copy=False))
        return out

    def _adjoint(self, y):
        dt = work_dtype(y)
        c = self._masks(dt)
        out = np.zeros(self.ishape, dtype=dt)
        for k, row in enumerate(self.warps):
            yk = y[k].astype(dt, copy=False)
            for l, w in enumerate(row):
                out[l] += w.apply_adjoint(c[k, l] * yk)
        return out

    def row_norms_sq(self) -> np.ndarray:
        r""":math:`\mathrm{diag}(HH^\top) = \sum_l C_{k,l}^2 \odot \|W_{k,l}\|^2_\text{rows}`."""
        out = np.zeros(self.oshape, dtype=np.float64)
        for k, row in enumerate(self.warps):
            for l, w in enumerate(row):
                out[k] += self.mask_images[k, l].astype(np.float64) ** 2 * w.norm_parts()[0]
        return out

    def __repr__(self):
        return (f"<BandWarpCassi {self.n_views} view(s), {self.n_bands} bands: "
                f"{self.ishape} -> {self.oshape}>")
