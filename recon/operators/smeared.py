r"""Mask, then shift and smear: multi-view CASSI whose bands each disperse over a short kernel.

A band of finite width :math:`[\lambda_\mathrm{lo}, \lambda_\mathrm{hi}]` does not land at one
sensor offset: the prism spreads it over :math:`\varphi(\lambda_\mathrm{lo}) \ldots
\varphi(\lambda_\mathrm{hi})`, up to ~3 px for a 25 nm band in the blue.  The instrument masks
the scene *first* and then disperses, so the forward model of view :math:`k` is

.. math::

    g_k = \sum_l D_{k,l}\big(M_k \odot W_k f_l\big), \qquad
    D_{k,l} = \sum_{j=0}^{T-1} w_{k,l,j}\, T_{s_{k,l} + j},

with :math:`M_k` the view's mask in view coordinates (:math:`H_v \times W_v`), :math:`W_k` the
geometric map, :math:`T_a` the placement of a view image at column :math:`a` of the
:math:`H_v \times W_m` measurement (an integer shift) and :math:`w_{k,l,\cdot}` the band's
*smear kernel* starting at column :math:`s_{k,l}`.  The adjoint is

.. math:: f_l = \sum_k W_k^\top\Big(M_k \odot \sum_j w_{k,l,j}\, T_{s_{k,l}+j}^\top g_k\Big).

The kernel of a band whose content lands at sub-pixel positions :math:`p` distributed as
:math:`\rho(p)` is :math:`w_j = \int \rho(p)\, \Lambda(s + j - p)\, dp` (:math:`\Lambda` the
unit hat: a piecewise-constant image shifted by :math:`p` and integrated over the sensor
pixels is its linear interpolation).  :func:`taps_from_positions` computes it from positions
sampled evenly across each band; one position per band gives the two linear-interpolation taps
:math:`(1-t, t)` of :class:`~recon.operators.cassi.CassiOperator`, which this operator then
equals.

``row_norms_sq`` is closed form: with :math:`A = \mathrm{diag}(M_k) W_k` and
:math:`P_d[u] = \langle A_u, A_{u+d}\rangle` (horizontal neighbours at lag :math:`d`; only
:math:`d = 0` for permutation warps), row :math:`c` of band :math:`l` has
:math:`\sum_{j,j'} w_j w_{j'} P_{|j-j'|}[c - s - \max(j, j')]`.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.operators.dispersion import SNAP_TOL, work_dtype
from recon.operators.mask import InPrecision, as_mask
from recon.operators.warp import as_warps, cube_shape_of

#: Kernel weights at or below this are dropped (the zero padding of a (K, L, T) table).
WEIGHT_TOL = 1e-9


def taps_from_positions(positions) -> tuple[np.ndarray, np.ndarray]:
    r"""Smear kernels from sub-pixel landing positions sampled evenly across each band.

    Each sample :math:`p` (equal weight :math:`1/S`) contributes its linear-interpolation taps
    :math:`(1 - t)` at :math:`\lfloor p\rfloor` and :math:`t` at :math:`\lfloor p\rfloor + 1`,
    :math:`t = p - \lfloor p\rfloor`; positions within :data:`SNAP_TOL` of an integer are taken
    as that integer (an exact copy, one tap).  The weights of a band sum to 1.

    Parameters
    ----------
    positions : (..., S) array_like
        Column where view column 0 lands for S wavelengths spread evenly over each band
        (e.g. (K, L, S)); non-negative.

    Returns
    -------
    start : (...) int64
        First column of each kernel (:math:`\lfloor\min p\rfloor`).
    weights : (..., T) float64
        Kernel weights, zero-padded to the longest kernel ``T``.
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim < 1 or p.shape[-1] < 1 or not np.all(np.isfinite(p)):
        raise InputError(f"positions must be a finite (..., S) array, got shape {p.shape}")
    r = np.round(p)
    p = np.where(np.abs(p - r) < SNAP_TOL, r, p)
    if np.min(p) < 0:
        raise InputError(f"positions must be >= 0, got min {np.min(p):g}")
    start = np.floor(p.min(axis=-1))
    rel = p - start[..., None]
    a = np.floor(rel).astype(np.int64)
    t = rel - a
    n_taps = int(a.max()) + 2
    lead = p.shape[:-1]
    flat_a = a.reshape(-1, p.shape[-1])
    flat_t = t.reshape(-1, p.shape[-1])
    w = np.zeros((flat_a.shape[0], n_taps), dtype=np.float64)
    row = np.repeat(np.arange(flat_a.shape[0]), p.shape[-1])
    s = float(p.shape[-1])
    np.add.at(w, (row, flat_a.ravel()), (1.0 - flat_t.ravel()) / s)
    np.add.at(w, (row, flat_a.ravel() + 1), flat_t.ravel() / s)
    w[w <= WEIGHT_TOL] = 0.0
    used = np.nonzero(w.any(axis=0))[0]
    w = w[:, :int(used.max()) + 1] if used.size else w[:, :1]
    return start.astype(np.int64).reshape(lead), w.reshape(lead + (w.shape[1],))


def smear_matrix(start: int, weights, w_in: int, w_out: int) -> np.ndarray:
    r"""Dense :math:`D` of one band acting on one row, ``(w_out, w_in)``:
    :math:`D[x + s + j, x] = w_j` (for references and the mask recovery's normal matrix)."""
    d = np.zeros((w_out, w_in), dtype=np.float64)
    x = np.arange(w_in)
    for j, wj in enumerate(np.asarray(weights, dtype=np.float64)):
        if wj != 0.0:
            d[x + start + j, x] += wj
    return d


class SmearedCassi(LinearOperator):
    r"""Multi-view CASSI with per-view masks and per-band smear kernels,
    ``(L, H, W) -> (K, Hv, Wm)`` (see the module docstring).

    Parameters
    ----------
    masks : (K, Hv, Wv) or (Hv, Wv) array_like
        :math:`M_k` in view coordinates (a 2-D array is one view).
    tap_start : (K, L) or (L,) array_like of int
        First measurement column :math:`s_{k,l} \ge 0` of each band's kernel (one row shared
        by all views, or one per view).
    tap_weights : (K, L, T) or (L, T) array_like
        Kernel weights :math:`w_{k,l,j}` (finite; zero entries are padding).
    warps : sequence of (Warp or None), optional
        :math:`W_k` per view (``None`` = identity).
    cube_shape : (L, H, W), optional
        Band-major scene shape; defaults to the input shape of the first warp that has one,
        else :math:`(L, H_v, W_v)`.
    width : int, optional
        Measurement width :math:`W_m`; defaults to the smallest that holds every kernel,
        :math:`W_v + \max(s + j)` over the non-zero taps.

    Attributes
    ----------
    masks : (K, Hv, Wv) float32
    tap_start : (K, L) int64
    tap_weights : (K, L, T) float64
    n_views, n_bands : int
    """

    def __init__(self, masks, tap_start, tap_weights, warps=None, cube_shape=None, width=None):
        m = np.asarray(masks)
        if m.ndim == 2:
            m = m[None]
        self.masks = as_mask(m, name="masks", ndim=3)
        k, hv, wv = self.masks.shape
        try:
            s = np.asarray(tap_start, dtype=np.float64)
            w = np.array(tap_weights, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("tap_start and tap_weights must be numeric arrays") from None
        if s.ndim == 1:
            s = np.broadcast_to(s, (k, s.size))
        if w.ndim == 2:
            w = np.broadcast_to(w, (k,) + w.shape)
        if s.ndim != 2 or s.shape[0] != k or s.shape[1] < 1:
            raise InputError(f"tap_start must be (L,) or (K={k}, L), got shape "
                             f"{np.shape(tap_start)}")
        n_bands = s.shape[1]
        if w.ndim != 3 or w.shape[:2] != (k, n_bands) or w.shape[2] < 1:
            raise InputError(f"tap_weights must be (L={n_bands}, T) or (K={k}, L, T), got shape "
                             f"{np.shape(tap_weights)}")
        if not (np.all(np.isfinite(s)) and np.all(np.isfinite(w))):
            raise InputError("tap_start and tap_weights must be finite")
        if np.any(s != np.round(s)) or np.min(s) < 0:
            raise InputError("tap_start must hold non-negative integers")
        self.tap_start = s.astype(np.int64)
        self.tap_weights = np.ascontiguousarray(w)
        # Per (k, l): the non-zero taps as (column, weight) pairs.
        self._taps = [[[(int(self.tap_start[i, l]) + j, float(wj))
                        for j, wj in enumerate(self.tap_weights[i, l]) if wj != 0.0]
                       for l in range(n_bands)] for i in range(k)]
        last = max((c for row in self._taps for band in row for c, _ in band), default=0)
        wm = wv + last if width is None else int(width)
        if wm < wv + last:
            raise InputError(f"a kernel reaches column {last} + view width {wv} > measurement "
                             f"width {wm}")
        warps = as_warps(warps, k, "masks")
        cs = cube_shape_of(cube_shape, n_bands, warps, (hv, wv))
        bound = []
        for i, x in enumerate(warps):
            out_shape = x.out_shape if x.out_shape is not None else (hv, wv)
            if tuple(out_shape) != (hv, wv):
                raise InputError(f"view {i}: warped image {tuple(out_shape)} != mask shape "
                                 f"{(hv, wv)}")
            bound.append(x.bind(cs[1:], (hv, wv)))
        self.warps = bound
        self.n_views, self.n_bands = k, n_bands
        self._masks = InPrecision(self.masks)
        self._row_norms = None
        super().__init__(cs, (k, hv, wm))

    def _forward(self, x):
        dt = work_dtype(x)
        x = x.astype(dt, copy=False)
        masks = self._masks(dt)
        hv, wv = self.masks.shape[1:]
        out = np.zeros(self.oshape, dtype=dt)
        z = np.empty((hv, wv), dtype=dt)
        buf = np.empty((hv, wv), dtype=dt)
        for k, warp in enumerate(self.warps):
            xv = warp.apply(x)
            for l, taps in enumerate(self._taps[k]):
                np.multiply(xv[l], masks[k], out=z)
                for c, wj in taps:
                    d = out[k, :, c:c + wv]
                    if wj == 1.0:
                        np.add(d, z, out=d)
                    else:
                        np.multiply(z, dt(wj), out=buf)
                        np.add(d, buf, out=d)
        return out

    def _adjoint(self, y):
        dt = work_dtype(y)
        y = y.astype(dt, copy=False)
        masks = self._masks(dt)
        hv, wv = self.masks.shape[1:]
        out = np.zeros(self.ishape, dtype=dt)
        buf = np.empty((hv, wv), dtype=dt)
        for k, warp in enumerate(self.warps):
            acc = warp.accumulate_view(out)
            tmp = np.zeros((self.n_bands, hv, wv), dtype=dt)
            for l, taps in enumerate(self._taps[k]):
                z = tmp[l]
                for c, wj in taps:
                    np.multiply(y[k, :, c:c + wv], dt(wj), out=buf)
                    np.add(z, buf, out=z)
                np.multiply(z, masks[k], out=z)
            if acc is not None:
                acc += tmp
            else:
                out += warp.apply_adjoint(tmp)
        return out

    def row_norms_sq(self) -> np.ndarray:
        r"""Diagonal of :math:`HH^\top` in closed form (module docstring)."""
        if self._row_norms is None:
            out = np.zeros(self.oshape, dtype=np.float64)
            wv = self.masks.shape[2]
            n_lags = max(len(t) and (t[-1][0] - t[0][0] + 1) for row in self._taps for t in row)
            for k, warp in enumerate(self.warps):
                m = self.masks[k].astype(np.float64)
                lags = _lag_products(warp, max(n_lags, 1))
                p = [m[:, :wv - d] * m[:, d:] * c if c is not None else None
                     for d, c in enumerate(lags)]
                for taps in self._taps[k]:
                    for i, (c, wj) in enumerate(taps):
                        out[k, :, c:c + wv] += wj * wj * p[0]
                        for c2, wj2 in taps[:i]:
                            d = c - c2
                            if p[d] is not None:
                                out[k, :, c:c + wv - d] += 2.0 * wj * wj2 * p[d]
            self._row_norms = out
        return self._row_norms.copy()

    def __repr__(self):
        t = max(len(b) for row in self._taps for b in row)
        return (f"<SmearedCassi {self.n_views} view(s), {self.n_bands} bands, <= {t} taps: "
                f"{self.ishape} -> {self.oshape}>")


def _lag_products(warp, n_lags: int) -> list:
    r"""``[n, c_1, ..., c_{n_lags-1}]``: :math:`c_d[y, u] = \langle W_{(y,u)}, W_{(y,u+d)}\rangle`
    (``(Hv, Wv - d)``), ``None`` where those rows never overlap (permutations, or no column)."""
    n, c1 = warp.norm_parts()
    out = [np.asarray(n, dtype=np.float64)]
    if n_lags < 2:
        return out
    if warp.is_permutation:
        return out + [None] * (n_lags - 1)
    hv, wv = warp.out_shape
    out.append(None if c1 is None or wv < 2 else np.asarray(c1, dtype=np.float64))
    if n_lags > 2:
        mat = warp.matrix().tocsr()
        idx = np.arange(hv * wv).reshape(hv, wv)
        for d in range(2, n_lags):
            if d >= wv:
                out.append(None)
                continue
            left = idx[:, :-d].ravel()
            c = np.asarray(mat[left].multiply(mat[left + d]).sum(axis=1)).reshape(hv, wv - d)
            out.append(c if np.any(c) else None)
    return out
