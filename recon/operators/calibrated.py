r"""Calibrated CASSI: measured per-band mask images on the sensor instead of mask + shift.

Standard CASSI calibration captures, band by band, the image of the coded aperture on the
sensor under uniform monochromatic light (the "shifted masks" :math:`C_{k,l}`, already
deconvolved for diffraction).  The forward model becomes

.. math::

    g_k = \sum_l C_{k,l} \odot S_{k,l}\big(W_k f_l\big), \qquad
    f_l = \sum_k W_k^\top S_{k,l}^\top\big(C_{k,l} \odot g_k\big),

where :math:`S_{k,l}` places the view image (width :math:`W_v`) at its measured dispersion
offset :math:`\varphi_{k,l}` on the sensor crop (linear interpolation for sub-pixel offsets).
Unlike :class:`~recon.operators.cassi.CassiOperator`, the offsets here are *absolute* column
positions on the crop of width :math:`W_m` the mask images were cut to, not normalised: each
band must land inside it.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.operators.dispersion import as_offsets, shift_row_norms, split, work_dtype
from recon.operators.mask import InPrecision, as_mask
from recon.operators.warp import as_warps, cube_shape_of


class CalibratedCassi(LinearOperator):
    r"""Multi-view CASSI from measured per-band sensor masks, ``(L, H, W) -> (K, Hv, Wm)``.

    Parameters
    ----------
    mask_images : (K, L, Hv, Wm) or (L, Hv, Wm) array_like
        :math:`C_{k,l}` on the sensor (a 3-D array is one view).
    offsets : (L,) or (K, L) array_like of float
        Absolute column where column 0 of the view image lands for each band (+ = larger x);
        one row shared by all views or one per view.  Must satisfy
        :math:`0 \le \varphi` and :math:`\lceil\varphi\rceil + W_v \le W_m`.
    warps : sequence of (Warp or None), optional
        :math:`W_k` per view (``None`` = identity).
    cube_shape : (L, H, W), optional
        Band-major scene shape; defaults to the input shape of the first warp that has one,
        else :math:`(L, H_v, W_m - \lceil\max\varphi\rceil)`.

    Attributes
    ----------
    mask_images : (K, L, Hv, Wm) float32
    offsets : (K, L) float64
    n_views, n_bands : int
    """

    def __init__(self, mask_images, offsets, warps=None, cube_shape=None):
        c = np.asarray(mask_images)
        if c.ndim == 3:
            c = c[None]
        self.mask_images = as_mask(c, name="mask_images", ndim=4)
        k, n_bands, hv, wm = self.mask_images.shape
        phi = np.asarray(offsets, dtype=np.float64) if not isinstance(offsets, np.ndarray) \
            else offsets.astype(np.float64)
        if phi.ndim == 1:
            table = np.stack([as_offsets(phi, n_bands)] * k)
        elif phi.ndim == 2 and phi.shape[0] == k:
            table = np.stack([as_offsets(r, n_bands, name=f"offsets of view {i}")
                              for i, r in enumerate(phi)])
        else:
            raise InputError(f"offsets must be (L,) or (K={k}, L), got shape {phi.shape}")
        if np.min(table) < 0:
            raise InputError(f"calibrated offsets are absolute sensor columns and must be >= 0, "
                             f"got min {np.min(table):g}")
        warps = as_warps(warps, k, "mask_images")
        cs = cube_shape_of(cube_shape, n_bands, warps, (hv, wm - int(np.ceil(np.max(table)))))
        bound = []
        for i, w in enumerate(warps):
            out_shape = w.out_shape if w.out_shape is not None else cs[1:]
            if out_shape[0] != hv:
                raise InputError(f"view {i}: warped image height {out_shape[0]} != mask image "
                                 f"height {hv}")
            bound.append(w.bind(cs[1:], out_shape))
        self.warps = bound
        self.offsets = table
        self._parts = [[split(p) for p in row] for row in table]
        for i, (w, row) in enumerate(zip(bound, self._parts)):
            wv = w.out_shape[1]
            for l, (a, t) in enumerate(row):
                if a + wv + (t > 0) > wm:
                    raise InputError(f"view {i} band {l}: offset {table[i, l]:g} + view width {wv}"
                                     f" does not fit in the mask image width {wm}")
        self.n_views, self.n_bands = k, n_bands
        self._cmasks = InPrecision(self.mask_images)
        self._row_norms = None
        super().__init__(cs, (k, hv, wm))

    def _forward(self, x):
        dt = work_dtype(x)
        x = x.astype(dt, copy=False)
        cm = self._cmasks(dt)
        out = np.zeros(self.oshape, dtype=dt)
        for k, warp in enumerate(self.warps):
            xv = warp.apply(x)
            wv = warp.out_shape[1]
            buf = np.empty(warp.out_shape, dtype=dt)
            for l, (a, t) in enumerate(self._parts[k]):
                c = cm[k, l]
                d0 = out[k, :, a:a + wv]
                np.multiply(xv[l], c[:, a:a + wv], out=buf)
                if t == 0.0:
                    np.add(d0, buf, out=d0)
                    continue
                d1 = out[k, :, a + 1:a + 1 + wv]
                buf *= 1.0 - t
                np.add(d0, buf, out=d0)
                np.multiply(xv[l], c[:, a + 1:a + 1 + wv], out=buf)
                buf *= t
                np.add(d1, buf, out=d1)
        return out

    def _adjoint(self, y):
        dt = work_dtype(y)
        y = y.astype(dt, copy=False)
        cm = self._cmasks(dt)
        out = np.zeros(self.ishape, dtype=dt)
        for k, warp in enumerate(self.warps):
            wv = warp.out_shape[1]
            acc = warp.accumulate_view(out)
            tmp = np.empty((self.n_bands,) + warp.out_shape, dtype=dt)
            buf = np.empty(warp.out_shape, dtype=dt)
            for l, (a, t) in enumerate(self._parts[k]):
                c = cm[k, l]
                z = tmp[l]
                np.multiply(y[k, :, a:a + wv], c[:, a:a + wv], out=z)
                if t != 0.0:
                    z *= 1.0 - t
                    np.multiply(y[k, :, a + 1:a + 1 + wv], c[:, a + 1:a + 1 + wv], out=buf)
                    buf *= t
                    z += buf
            if acc is not None:
                acc += tmp
            else:
                out += warp.apply_adjoint(tmp)
        return out

    def row_norms_sq(self) -> np.ndarray:
        r"""Diagonal of :math:`HH^\top`: :math:`\sum_l C_{k,l}^2 \|(S_{k,l}W_k)_i\|^2`."""
        if self._row_norms is None:
            out = np.zeros(self.oshape, dtype=np.float64)
            q = np.empty(self.oshape[1:], dtype=np.float64)
            for k, warp in enumerate(self.warps):
                n, c = warp.norm_parts()
                for l, (a, t) in enumerate(self._parts[k]):
                    q.fill(0.0)
                    shift_row_norms(n, c, a, t, q)
                    out[k] += self.mask_images[k, l].astype(np.float64) ** 2 * q
            self._row_norms = out
        return self._row_norms.copy()

    def __repr__(self):
        return (f"<CalibratedCassi {self.n_views} view(s), {self.n_bands} bands: "
                f"{self.ishape} -> {self.oshape}>")
